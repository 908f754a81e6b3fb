"""The model a designer names: lens, design, sensor, spectrum, glass, camera, field geometry, numerics."""
