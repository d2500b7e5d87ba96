"""The perch_operator node and the mission it coordinates: crop, stage calls, proposals, review, confirm, markers and views."""
