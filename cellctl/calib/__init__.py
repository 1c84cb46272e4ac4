"""Zhang stereo calibration of the rig from checkerboard pairs: pair discovery, corner detection, outlier
rejection and the report (the result is a cellctl.vision.calibration.Calibration)."""
