"""Segmentation stage of Perch: planar surfaces of a room mesh."""
