"""Shared core of Perch: mesh I/O and validation, message conversions, ray casting, configuration, the procedural scene generator, the perch CLI and launcher."""
