"""Reconstruction stage of Perch: RGB-D bags or topics to a clean gravity-aligned room mesh."""
