# Stage: sign stitching (signsplat sign). For the default multi-view scene's demo avatar, every
# configured sentence becomes a gloss plan, a stitched SMPL-X track, the avatar video and the 2D
# keypoint baseline video, plus one stitch_eval table. The `stitch` config section is validated
# against workflow/schemas/stages/stitch.schema.yaml. No science here.
import copy
import shlex
from types import SimpleNamespace

from signsplat.stitch.cli import sentence_id

STITCH_CFG = validate(copy.deepcopy(config.get("stitch", {})), "stages/stitch.schema.yaml",
                      "config key 'stitch'")
STITCH_VARIANT = "demo"
# sentence id (output stem) -> sentence
STITCH_SENTENCES = {sentence_id(s): s for s in STITCH_CFG["sentences"]}
# the default multi-view scene (PLAN.default_scene), when it is synthetic
STITCH_SCENES = [s for s in [PLAN.default_scene] if s in SCENES]


def stitch_files(suffix):
    return [f"{RESULTS}/{{scene}}/stitched/{i}{suffix}" for i in STITCH_SENTENCES]


def stitch_cameras(wildcards):
    """The cameras the avatar was trained with (fitted or ground truth)."""
    return avatar_inputs(SimpleNamespace(scene=wildcards.scene, variant=STITCH_VARIANT))["cameras"]


rule stitch_video:
    input:
        checkpoint=f"{RESULTS}/{{scene}}/avatar/{STITCH_VARIANT}/checkpoint.pt",
        body=rules.body_model.output[0],
        library=rules.gloss_library.output[0],
        cameras=stitch_cameras,
    output:
        videos=[report(f, caption="../report/stitch_video.rst", category="8. Stitched video")
                for f in stitch_files(".mp4")],
        baselines=[report(f, caption="../report/stitch_baseline.rst",
                          category="8. Stitched video") for f in stitch_files(".baseline2d.mp4")],
        tracks=stitch_files(".smplx.parquet"),
        plans=stitch_files(".plan.txt"),
        plans_json=stitch_files(".plan.json"),
        eval=f"{RESULTS}/{{scene}}/stitched/stitch_eval.parquet",
    params:
        sentences=" ".join(shlex.quote(s) for s in STITCH_SENTENCES.values()),
        ids=" ".join(f"--id {i}" for i in STITCH_SENTENCES),
        cfg=as_json(STITCH_CFG),
        out=f"{RESULTS}/{{scene}}/stitched",
    log:
        f"{RESULTS}/_logs/{{scene}}/stitch_video.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/stitch_video.tsv"
    priority: AVATAR
    threads: job_threads
    resources:
        mem_mb=3000,
        runtime=60,
    shell:
        "{PY} -m signsplat sign {params.sentences} {params.ids} --library {input.library:q}"
        " --out {params.out:q} --config-json {params.cfg:q} --avatar {input.checkpoint:q}"
        " --body {input.body:q} --cameras {input.cameras:q} --threads {threads}"
        " --device {DEVICE}"
        " --eval {output.eval:q} > {log} 2>&1"


def stitch_outputs():
    """The stitched videos and their table (in `all`), none without sentences."""
    if not STITCH_SENTENCES:
        return []
    return expand(rules.stitch_video.output.eval, scene=STITCH_SCENES) + expand(
        f"{RESULTS}/{{scene}}/stitched/{{id}}.mp4", scene=STITCH_SCENES,
        id=list(STITCH_SENTENCES))
