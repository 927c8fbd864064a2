"""Loaders and validators for telemetry files and real datasets."""
