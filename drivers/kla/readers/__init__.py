"""Readers of nanoindenter exports, one module per export family, over shared column/unit tables,
table splitting, curve analysis, file sniffing and plausibility checks. ``drivers.kla.export`` is the entry."""
