"""Placement stage of Perch: camera simulation, fitness and swarm search for camera perches."""
