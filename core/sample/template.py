"""The commented ``sample.toml`` that ``aeni sample new`` writes: every field, what it means, its unit."""

from __future__ import annotations

SAMPLE_TEMPLATE = """\
# A sample on the stage (aeni sample check FILE validates it and draws it).
# Every coordinate is in stage µm, as read off the instrument (not mm).
name = "NiTiCu-library-07"
profile = "kla-imicro"          # instrument profile: kla-imicro, kla-imicro-film, or a profile TOML file
lattice_n = 50                  # candidate centres per side (N×N over the calibrated area)

[corners]                       # the four corners as the operator reads them: x, y and the surface height z
tl = { x_um = 11937.2, y_um = 9198.4, z_um = 251.2 }
tr = { x_um = 13441.2, y_um = 9271.9, z_um = 254.2 }
br = { x_um = 13497.9, y_um = 8078.5, z_um = 253.0 }
bl = { x_um = 12000.0, y_um = 8000.0, z_um = 250.0 }

[safety]
dz_safe_um = 5.0                # a local sub-grid stays within this height of its program's centre
r_excl_um = 20.0                # no indent closer than this to an earlier one
edge_band_um = 25.0             # no indent closer than this to the sample's edge
stage_rect_um = [0.0, 0.0, 100000.0, 100000.0]   # the stage's safe travel: x_min, y_min, x_max, y_max

# Regions no indent may enter: clamps, scratches, earlier test areas. Add as many as needed.
[[exclusions]]
circle_um = [12700.0, 8650.0, 150.0]              # x, y, radius
[[exclusions]]
polygon_um = [[12000.0, 8000.0], [12450.0, 8023.6], [11981.2, 8359.5]]

[earlier]                       # indents from earlier work on this sample, kept r_excl_um away from
# indents_csv = "earlier.csv"   # columns x_um, y_um; relative paths are relative to this file
journals = []                   # journals (.sqlite) of earlier runs on this sample
"""
