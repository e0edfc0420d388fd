"""Running the chain over a video: decoding and encoding, frame sources, windows, segments and threads, observers."""
