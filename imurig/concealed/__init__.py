"""The concealed-effect suite: recordings with one library effect hidden at a known size, scored against the diagnosis."""
