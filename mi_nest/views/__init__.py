"""Views into a stress field, true or reconstructed: virtual slices, novel views, principal stresses, the viewer."""
from .slicing import Plane, Region, SliceError, SliceSpec, slice_render, slice_render_white_light
from .source import ViewSource, open_source

__all__ = ["Plane", "Region", "SliceError", "SliceSpec", "slice_render", "slice_render_white_light", "ViewSource",
           "open_source"]
