"""Files in and out: stress grids, multichannel EXR, PNG previews."""
