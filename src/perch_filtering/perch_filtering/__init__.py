"""Filtering stage of Perch: surface regions where a drone can safely perch."""
