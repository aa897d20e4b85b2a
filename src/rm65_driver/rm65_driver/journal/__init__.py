"""The weld journal: the writer, its record format, reading it back, repairing it, durable file writes."""
