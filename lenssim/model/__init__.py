"""The model a designer names: lens, surface, design, sensor, spectrum, glass, camera, field geometry, numerics."""
