"""The algorithm: pure numpy/OpenCV stages with typed configs and results. Never imports rerun or matplotlib."""
