"""Sans-I/O MAVLink layer: codec (bytes ↔ messages), tlog framing, timelines."""
