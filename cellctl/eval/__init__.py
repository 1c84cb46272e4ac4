"""Lab tooling, not line code: Middlebury evaluation (data, methods, report, pictures, the paper's table),
the matcher speed benchmark and the sole measurement benchmark."""
