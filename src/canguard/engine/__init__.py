"""The one loop: context, clock, task gate and stops, events, the engine itself."""
