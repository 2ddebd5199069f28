"""Video sequences: one world, many views — rendered frame by frame, resumable, on Ray.

* :mod:`arlight.sequence.poses` — poses files, keyframes, slerp interpolation;
* :mod:`arlight.sequence.frames` — input frames (a folder of images or a video file);
* :mod:`arlight.sequence.job` — the job (world, camera, per-frame poses, method) and
  :func:`~arlight.sequence.job.render_frame` (prepare once per process, render per frame);
* :mod:`arlight.sequence.store` — the output folder, written frame by frame (resume);
* :mod:`arlight.sequence.runner` — the sequential loop or Ray, progress, video, summary;
* :mod:`arlight.sequence.distributed` — Ray (imported only when a run asks for it);
* :mod:`arlight.sequence.synthetic_video` — a synthetic sequence with per-frame ground truth.

``arlight sequence SCENE --frames DIR --poses poses.txt -m METHOD -o OUT``; see
``docs/sequence.md``.
"""
