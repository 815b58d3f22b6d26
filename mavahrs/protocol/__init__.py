"""Sans-I/O MAVLink layer: codec (bytes ↔ messages), tlog framing, signing (sample timing is in mavahrs.ingest)."""
