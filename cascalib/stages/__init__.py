"""The stages of the cascade, in the order data flows through them.

* :mod:`~cascalib.stages.single_view` (stage I): focal length and ground plane per camera;
* :mod:`~cascalib.stages.align` (stages II-IV): time synchronisation, rotation search and ICP on
  the ground plane, giving all cameras one world frame and one clock;
* :mod:`~cascalib.stages.multiview_path` (the multi-view start): replaces stages I-IV where
  stage I cannot decide a camera, placing the cameras from the people's joints;
* :mod:`~cascalib.stages.refine` (stage V): the GTSAM bundle adjustment and the final
  triangulation.

Every module of each stage, and what goes in and out: ``docs/architecture.md``.
"""
