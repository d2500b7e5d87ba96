"""The command line: `perch plan`/`demo`, `perch operator ...`, `record`, `replay`, `dispatch`, `batch` and their runner."""
