"""The end-to-end runner (`gspi-run`): assets, methods, evaluation, records, tracking."""
