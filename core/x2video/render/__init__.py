"""The render's orchestration: the `Renderer` (plan, run the tier, emit events), its settings and events, and the frame writer."""
