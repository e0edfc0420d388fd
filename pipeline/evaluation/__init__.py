"""Judging the output: stability metrics, synthetic ground truth, completion and dynamic-scene scores."""
