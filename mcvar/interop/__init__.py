"""Other renderers' views of mcvar's scenes (layer 5).

=============  ===============================================================
module         holds
=============  ===============================================================
``mitsuba``    :func:`to_mitsuba` (a :class:`~mcvar.scene.Scene` as a Mitsuba 3
               scene dictionary for ``mi.load_dict``) and
               :func:`render_mitsuba` (that scene rendered by Mitsuba, as an
               ``(H, W, 3)`` array in mcvar's orientation)
=============  ===============================================================

Mitsuba 3 is an optional extra (``pip install 'mcvar[mitsuba]'``), imported
only when one of these functions runs (docs/mitsuba.md).
"""
from __future__ import annotations

from .mitsuba import render_mitsuba, scene_fingerprint, to_mitsuba

__all__ = ["to_mitsuba", "render_mitsuba", "scene_fingerprint"]
