"""atr-node: automatic target recognition for mine-hunting AUV synthetic aperture sonar.

The package is laid out by architecture (see README):

- ``records``: typed records (sonar tiles, navigation) and their validation;
- ``geo``: the mission metric frame and pixel georeferencing;
- ``io``: the ``.atrlog`` recording format;
- ``detectors``, ``simulation``, ``calibration``, ``fusion``: the algorithms of SPEC.md;
- ``node``: the on-vehicle service; ``commands``: the ``atr-node`` subcommands.

Link drivers live in the sibling top-level package ``hw``.
"""

__version__ = "0.1.0"
