"""Commands no stage runs: the CLI, the frame gallery, the resolution study, the offline plots page."""
