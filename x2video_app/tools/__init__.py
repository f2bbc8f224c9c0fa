"""Scripts for developing and checking the editor, not part of its window: the screenshots for the docs, the bundle's
self-test, and the event-loop tick probe the latency tests and bench read."""
