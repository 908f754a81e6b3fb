"""pipeline: the camera pipeline (photo -> linear -> spatially-variant blur -> noise -> restoration).

Not implemented yet (issue: camera pipeline). It will use :mod:`lenssim` for PSFs at any image
point (:func:`lenssim.psf_at`); ``lenssim`` never imports from here.
"""

__all__: list[str] = []
