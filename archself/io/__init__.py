"""Bytes and text on disk: reading files with caps, YAML 1.2 with positions, JSON data, atomic
outputs that never land on an input, and run traces (Parquet or JSON)."""
