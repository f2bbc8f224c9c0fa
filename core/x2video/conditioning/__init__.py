"""Stage 3 of a render: what the network sees of each frame (the shot's channels under the edits) and at which size."""
