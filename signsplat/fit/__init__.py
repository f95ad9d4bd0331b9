"""SMPL-X fitting to 2D whole-body keypoints (paper section 3.1, "3D Reconstruction Pipeline").

Modules
-------
- :mod:`filters`    One-Euro temporal filter and keypoint outlier rejection (numpy).
- :mod:`robust`     Geman-McClure and Huber kernels (torch).
- :mod:`cameras`    camera parametrisation, projection and initialisation without ground truth.
- :mod:`bodyfit`    differentiable keypoints from fit parameters (body model + hand limits).
- :mod:`objective`  the loss terms, each weight a named config field.
- :mod:`solver`     Adam / L-BFGS stages, batched over frames, chunked warm start.
- :mod:`levenberg_marquardt` the joint Levenberg-Marquardt stage over the whole sequence.
- :mod:`silhouette` person-mask terms; :mod:`flow` the optical-flow term.
- :mod:`sequence`   fitted / interpolated / missing frames and gap filling.
- :mod:`data`       reading inputs and writing ``smplx_fit`` / ``cameras_fit`` tables.
- :mod:`multiview`  joint body + camera solve over a sequence.
- :mod:`singleview` initialiser interface, default initialiser, low-learning-rate refinement.
- :mod:`evaluate`   accuracy metrics against ground truth (MPJPE, PA-MPJPE, cameras, jitter).
- :mod:`overlay`    diagnostic images: fitted skeleton drawn on the input.
- :mod:`mode`       which fit a scene gets (multi-view or single view).
- :mod:`run`        one scene's fit from files to files (read, clean, fit, evaluate, write).
- :mod:`cli`        the ``signsplat fit`` command (argument parsing, then :mod:`run`).

Measured histories of the settings: ``docs/fit.md``.
"""
