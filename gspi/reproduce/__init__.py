"""gspi-reproduce: each paper table by one resumable command at a named scale (docs/REPRODUCE.md)."""
