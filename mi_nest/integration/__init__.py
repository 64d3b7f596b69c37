"""The photoelastic integrator's parts; ``plugins/photoelastic.py`` is the plugin itself (properties,
the walk, the render and ray entry points).

``setup`` (what a render needs from the scene), ``methods`` (the models of the
ordered exponential, one object each), ``auto`` (the analysis behind the
``auto`` method), ``film`` (channels, pixel sums, developing) and ``guards``
(what the integrator refuses or warns about).
"""
