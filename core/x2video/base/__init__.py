"""The base: a shot's own path-traced frames, the pixels every tier renders over (docs/ARCHITECTURE.md, "The base").

Where a shot carries rgb on every frame, those frames are the base; where it carries rgb on keyframes only,
the frames between are filled from the nearest keyframes (`fill`); edits then render as differences over the
base (`difference`)."""
