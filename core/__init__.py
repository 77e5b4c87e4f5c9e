"""AE-NI core: sample and geometry, cost, surrogate, acquisition, policies, the safety interlock, engine and journal.

No UI, no instrument I/O, no ground truth (the emulator lives in drivers/sim/).
"""
