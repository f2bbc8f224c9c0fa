"""X2Video Studio: the PySide6 desktop editor (imports x2video, never the reverse)."""
