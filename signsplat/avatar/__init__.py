"""The SignSplat avatar (paper 3.2-3.5, 4.1-4.5): Gaussians anchored on the SMPL-X mesh.

Modules (each small, functional where it can be):

- ``config``: :func:`avatar_config` -> :class:`AvatarConfig` dataclasses from the validated
  ``avatar`` YAML section (schema ``workflow/schemas/stages/avatar.schema.yaml``, profiles
  ``demo`` and ``quality``).
- ``upsample``: :func:`upsample_mesh` points along long edges / at centres of large faces.
- ``model``: :class:`AvatarModel` (canonical Gaussians, eq. 3 displacement network, pose network
  Omega with four heads, per-part sigmoid scale bounds) -> :class:`PosedGaussians`.
- ``strategy``: :class:`MeshDensifyStrategy` density control on mesh faces (gsplat pattern).
- ``regularize``: neighbourhood variance over mesh-connected neighbourhoods, displacement terms.
- ``losses``: L1, D-SSIM, PSNR/SSIM, LPIPS from a local weight file.
- ``data``: scene tables -> :class:`SceneData`; novel-pose split.
- ``train``: :class:`AvatarTrainer` (accumulation, SMPL-X fine-tuning, checkpoints).
- ``checkpoint``: :func:`build_model` and :func:`load_avatar`, a trained avatar ready to render
  (also ``signsplat.avatar.load_avatar``, the package's public entry for other stages).
- ``evaluate``: :func:`evaluate_checkpoint` -> ``avatar_metrics`` and per-camera
  ``avatar_view_metrics`` rows (``views``).
- ``ply``: standard 3DGS PLY writer/reader. ``cli``: ``train-avatar`` and ``evaluate-avatar``.

Typical use::

    from signsplat.avatar.config import avatar_config
    from signsplat.avatar.data import load_scene
    from signsplat.avatar.train import AvatarTrainer
    cfg = avatar_config({"profile": "demo"})
    data = load_scene("sim/frames.parquet", "sim/cameras.parquet", "sim/smplx_gt.parquet")
    trainer = AvatarTrainer(BodyModel.from_file(path), data, cfg)
    trainer.run(checkpoint="checkpoint.pt")
"""

__all__ = ["load_avatar"]


def __getattr__(name: str):
    # imported on first use: the config and report modules import this package without torch
    if name == "load_avatar":
        from signsplat.avatar.checkpoint import load_avatar

        return load_avatar
    raise AttributeError(f"module 'signsplat.avatar' has no attribute {name!r}")
