"""Perch operator console: the mission in a browser, a client of the running graph."""
