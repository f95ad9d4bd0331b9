"""Synthetic signer scenes: scene specs, the effect registry, an independent mesh renderer,
the ``simulate`` stage, and the gloss library (``glosses``).

Modules are imported on use: ``signsplat.synth.mesh_render``, ``effects``, ``scene``,
``simulate``, ``glosses``, ``cli``.
"""
