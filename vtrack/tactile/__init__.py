"""Vision-based tactile sensing: calibration, photometric stereo, Poisson height, contact, shear, slip, force.

Modules (numpy/scipy/OpenCV only unless noted; torch is imported only by the MLP calibration):
- :mod:`~vtrack.tactile.pressset` press-set format (ball presses + labels + meta) and loaders;
- :mod:`~vtrack.tactile.calibration` colour(+position) -> surface gradient (LUT, MLP, photometric stereo);
- :mod:`~vtrack.tactile.poisson` height from gradients (DCT, FFT Frankot-Chellappa, masked LSQ);
- :mod:`~vtrack.tactile.contact` contact mask and contact statistics;
- :mod:`~vtrack.tactile.markers`, :mod:`~vtrack.tactile.slip`, :mod:`~vtrack.tactile.force`;
- :mod:`~vtrack.tactile.pipeline` :class:`TactilePipeline` (image -> :class:`TactileFrame`);
- :mod:`~vtrack.tactile.render` inverse model: height map -> tactile image (for the simulator);
- :mod:`~vtrack.tactile.evaluation` ball-press evaluation (fitted radius, normal error).
"""
