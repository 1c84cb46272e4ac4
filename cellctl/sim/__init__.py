"""Simulators that stand in for the cell's cameras: the stereo rig and the scenes it looks at."""
