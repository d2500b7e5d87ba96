"""Operator stage of Perch: crop, mission coordination, confirmation, waypoints, recording and replay."""
