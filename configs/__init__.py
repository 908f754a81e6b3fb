# Makes configs/ the package data `lenssim.configs` of an install (see pyproject.toml and
# lenssim/resources.py). The files here are the built-in sweep configs and named designs.
