"""Running the chain over a video: reading and writing, frame sources, the sliding window, threads, memory, observers."""
