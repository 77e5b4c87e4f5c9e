"""AE-NI core: geometry, cost, emulator, surrogate, acquisition, policies. No UI, no instrument I/O."""
