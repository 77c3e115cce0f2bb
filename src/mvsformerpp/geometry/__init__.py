"""Cameras, projection, warping and pixel conventions, written down once."""
