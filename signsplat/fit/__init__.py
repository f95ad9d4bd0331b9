"""SMPL-X fitting to 2D whole-body keypoints (paper section 3.1, "3D Reconstruction Pipeline").

Modules
-------
- :mod:`filters`    One-Euro temporal filter and keypoint outlier rejection (numpy).
- :mod:`robust`     Geman-McClure and Huber kernels (torch).
- :mod:`cameras`    camera parametrisation, projection and initialisation without ground truth.
- :mod:`bodyfit`    differentiable keypoints from fit parameters (body model + hand limits).
- :mod:`objective`  the loss terms, each weight a named config field.
- :mod:`solver`     Adam / L-BFGS stages, batched over frames, chunked warm start.
- :mod:`sequence`   fitted / interpolated / missing frames and gap filling.
- :mod:`data`       reading inputs and writing ``smplx_fit`` / ``cameras_fit`` tables.
- :mod:`multiview`  joint body + camera solve over a sequence.
- :mod:`singleview` initialiser interface, default initialiser, low-learning-rate refinement.
- :mod:`evaluate`   accuracy metrics against ground truth (MPJPE, PA-MPJPE, cameras, jitter).
- :mod:`overlay`    diagnostic images: fitted skeleton drawn on the input.
- :mod:`cli`        the ``signsplat fit`` command.
"""
