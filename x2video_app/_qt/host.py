"""`Host`: what the editor's controllers ask of the window they serve, and nothing more.

The controllers (`EditActions`, `ProjectController`) are given the Document, the undo stack, the render
controller and a Host; they never hold the main window. Their file and progress dialogs sit on the widget
given to them as their Qt parent.
"""
from __future__ import annotations

from typing import Protocol

from PySide6.QtWidgets import QMessageBox


class Host(Protocol):
    def status(self, text: str, timeout_ms: int = 0) -> None:
        """Show `text` in the status line (for `timeout_ms`; 0: until the next message)."""

    def show_error(self, title: str, text: str) -> None:
        """Tell the person something failed (the project stays as it was)."""

    def ask(
        self, title: str, text: str, buttons: QMessageBox.StandardButton, default: QMessageBox.StandardButton
    ) -> QMessageBox.StandardButton:
        """Ask a question with these buttons; the button chosen."""
