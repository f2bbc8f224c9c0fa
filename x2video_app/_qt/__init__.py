"""The editor's Qt half: the main window, its panels and widgets, and the controllers that run work in Qt workers
(render, live preview, edits, projects, export). Built on the Qt-free models of `x2video_app.state`."""
