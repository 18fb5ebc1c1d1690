"""python -m denoise.live: watch a scene rendered at 1 spp and denoised, live, in a browser.

Serves a local page (it prints the address; it opens nothing) that shows
SCENE path-traced at 1 spp with the export's G-buffers and denoised by the
chosen method, frame after frame. Drag to orbit, right-drag or Shift+drag to
pan, wheel to dolly, Alt+drag to move the first point light.
"""
from __future__ import annotations

if __name__ == "__main__":  # first: ./.venv's Python, the libLLVM, then Dr.Jit (see core.launcher)
    from core.launcher import start
    from core.start_up import NOTHING_WRITTEN
    start("python -m denoise.live", "denoise.live", stopped=NOTHING_WRITTEN)


from core.entry import finish

from .app import main

if __name__ == "__main__":
    finish(main())
