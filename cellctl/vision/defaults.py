"""The cell's measurement defaults, in one place: the config, the CLI and the measurement read them here.

A recipe or the cell config may override each; nothing else writes these numbers down again.
"""

from __future__ import annotations

#: Working depth range of the rig (mm from the left camera): a table ~550 mm below the rig and soles on it.
DEPTH_RANGE_MM: tuple[float, float] = (450.0, 650.0)
#: Glue path: how far inside the sole's edge (mm) and the spacing of its points along the path (mm).
GLUE_OFFSET_MM = 2.0
GLUE_SPACING_MM = 2.0
#: Their bounds: no dispenser places glue finer than 0.1 mm (1e-6 mm once grew the path to 18 GB).
GLUE_OFFSET_RANGE_MM: tuple[float, float] = (0.0, 50.0)
GLUE_SPACING_RANGE_MM: tuple[float, float] = (0.1, 50.0)
#: How far (mm) a glue height may stray from the sole's top: a path whose heights are expected to stray further
#: is refused (cellctl.vision.checks.check_glue_precision); its bounds.
GLUE_HEIGHT_TOLERANCE_MM = 1.0
GLUE_HEIGHT_TOLERANCE_RANGE_MM: tuple[float, float] = (0.1, 10.0)
#: The side-wall drafts (degrees) a recipe may state for a moulded sole (cellctl.vision.wall_draft), 0 excluded (a
#: vertical wall): a mould's draft is a few degrees; beyond 10 the wall shows to the cameras and the edge checks
#: refuse it whatever the recipe says.
WALL_DRAFT_RANGE_DEG: tuple[float, float] = (0.0, 10.0)
#: Pairs a cycle grabs and averages (cellctl.cameras.averaging): the sensor's noise falls by sqrt(n), which black soles
#: need for their glue heights; a cycle waits (n - 1) frame periods longer for them (~100 ms at 30 fps). The
#: measurement assumes it where a mean's count is not known (a mean replayed from the image log).
AVERAGED_FRAMES = 4
#: Pairs averaged in all when a cycle refused for its glue heights' precision on the mean measures the same still
#: sole once more ([cameras] retry_averaged_frames, cellctl.service.measuring; cellctl.vision.checks proposes it
#: only where the sensor's noise averaging further can bring the error under the limit): on eight, 8 of the 15
#: soles four fresh sets refused for it on four were measured right, none wrong (docs/sole-benchmark.md, fortieth
#: round). The limit is calibrated on eight (checks.GLUE_SD_SHARE_PER_DOUBLING).
MORE_EXPOSURES = 8
#: Results outside these ranges are no sole on this cell: refused, never published.
PLAUSIBLE_LENGTH_MM: tuple[float, float] = (100.0, 400.0)
PLAUSIBLE_HEIGHT_MM: tuple[float, float] = (0.5, 150.0)
