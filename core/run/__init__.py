"""A run: the engine, its state machine, and (later) the events it emits."""
