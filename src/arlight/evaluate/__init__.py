"""Evaluation harness: the papers' test scenes, ground truth, image metrics and reports.

* :mod:`arlight.evaluate.suite` — the scene suite (``list_scenes``, ``get_scene``);
* :mod:`arlight.evaluate.metrics` — RMSE, PSNR, SSIM, FLIP, signed error maps, flicker;
* :mod:`arlight.evaluate.harness` — methods × scenes runs with timing and memory;
* :mod:`arlight.evaluate.report` — Markdown/HTML report with image grids and plots;
* :mod:`arlight.evaluate.cli` — the ``arlight eval`` command.
"""
