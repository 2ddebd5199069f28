"""Live AR: ``arlight live`` — a camera or a video played at its own rate, a printed marker
tracked per frame, an interactive method rendering every frame through ``sequence``'s one
per-frame function, frames dropped (never queued) to stay live, shown in the studio page.

* :mod:`arlight.live.sources` — paced video, camera, unpaced; drop counting;
* :mod:`arlight.live.loop` — track → render → show, latency and stage log;
* :mod:`arlight.live.setup` — the job (calibrated camera, method, light estimate);
* :mod:`arlight.live.studio` — the studio page's live frame source;
* :mod:`arlight.live.record` — ``--record`` (video or frames), never over an input;
* :mod:`arlight.live.marker_video` — the bundled synthetic marker video.

See ``docs/live.md``.
"""
