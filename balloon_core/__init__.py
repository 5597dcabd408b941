"""The shared core below every program: the design and its schema, rotations, atmosphere, the wire,
samples, argv checks, progress, the stop flag and the measuring instrument (score, response, skill)."""
