"""Files: atomic writes, staged output folders, TOML reading, the package data (configs)."""
