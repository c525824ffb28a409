"""Evaluation protocol of GS-PI: reads the canonical layout, never imports gspi."""
