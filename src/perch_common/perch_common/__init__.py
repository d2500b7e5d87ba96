"""Shared core of Perch: mesh I/O and validation, message conversions, ray casting, configuration,
the procedural scene generator, the perch CLI and launcher.

Importing it changes nothing in the process: thread limits are applied by the entry points
(perch_common.threads).
"""
