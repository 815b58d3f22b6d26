"""The sample chain: decoded IMU samples → the filter's input rows (the array form: :mod:`mavahrs.ingest.arrays`)."""
