"""Optics: the optical-system protocol, paraxial and Seidel sums, ray trace, wavefront models, PSF/OTF banks,
PSF providers, the image model and the asphere cost."""
