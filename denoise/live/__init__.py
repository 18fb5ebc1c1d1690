"""``python -m denoise.live SCENE``: the scene rendered at 1 spp and denoised,
frame after frame, in a local web page (see docs/live.md)."""
