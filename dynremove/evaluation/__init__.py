"""Measuring the method: metrics, baselines, synthetic scenes, composites, eval, bench.

Above the pipeline: these modules run ``dynremove.pipeline`` and the baselines on
sets with ground truth; nothing in the method or the pipeline imports them.

* ``metrics``: Jaccard, PSNR/SSIM in a mask, whole-photo damage/leftover.
* ``baselines``: median stack (homography or homography + flow), Telea inpainting.
* ``synth``: deterministic synthetic multi-view scenes with ground truth.
* ``composite``: real objects pasted into real static multi-view sets.
* ``evaluate``: every method on every set below a folder (``dynremove eval``).
* ``bench``: stage timings, throughput, peak memory (``dynremove bench``).
"""
