"""softforce: an RGB-D camera and a finite element model as a force sensor for soft robots."""

__version__ = "0.1.0"
