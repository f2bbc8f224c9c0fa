"""The editor's Qt-free half: the Document and the render's state it holds, the small signal they are observed
through, what the viewer shows (display, compare views, the formula's preview), export, the model and demo sources.
Never imports Qt (an import-linter contract in pyproject.toml keeps it so): the widgets in `x2video_app._qt`
subscribe to these models, and tests drive them without a QApplication."""
