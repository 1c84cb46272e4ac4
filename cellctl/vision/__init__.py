"""From a stereo pair to a measured sole: calibration geometry, cloud, table, segmentation, outliers,
footprint, surface, measurement and the overlay picture. Knows nothing of cameras, PLCs or services."""
