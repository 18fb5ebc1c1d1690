"""Progress display: a bar over the jobs and a bar inside long renders.

Bars go to stderr, and only when stderr is a terminal: piped or redirected
output gets the result lines alone, one per scene, never interleaved with a
bar's redraws. Bars appear only for work that takes more than a second
(tqdm's ``delay``). The in-render bar is fed by Mitsuba's own progress reports
(scalar variants report as blocks finish; a JIT render is one kernel and
reports at its end).
"""
from __future__ import annotations

import sys

import mitsuba as mi
from tqdm import tqdm

from core.entry import printable

#: Mitsuba messages not worth repeating to users of render.py
_QUIET = ("SamplingIntegrator Python implementations will have terrible performance",)


class _TqdmAppender(mi.Appender):
    def __init__(self, bars: bool, warnings: bool = True):
        super().__init__()
        self.bars, self.warnings = bars, warnings
        self.bar: tqdm | None = None

    def append(self, level, text):
        # --quiet: "nothing but errors", so Mitsuba's warnings go too
        lowest = mi.LogLevel.Warn if self.warnings else mi.LogLevel.Error
        if level >= lowest and not any(q in text for q in _QUIET):
            tqdm.write(text, file=sys.stderr)

    def log_progress(self, progress, name, formatted, eta, ptr=None):
        if not self.bars:
            return
        if self.bar is None:
            self.bar = tqdm(total=100, desc=name, unit="%", delay=1.0, leave=False, file=sys.stderr,
                            bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}")
        self.bar.update(round(100 * progress) - self.bar.n)
        if progress >= 1.0:
            self.bar.close()
            self.bar = None


def log_to_stderr() -> None:
    """Mitsuba's messages on stderr, as every command's own: its default
    appender writes them to stdout, which carries only what a command is for."""
    logger = mi.logger()
    appenders = [logger.appender(i) for i in range(logger.appender_count())]
    if not any(isinstance(a, _TqdmAppender) for a in appenders):
        logger.clear_appenders()
        logger.add_appender(_TqdmAppender(bars=False))


def bars_wanted(enabled: bool = True) -> bool:
    """Whether to draw progress bars: asked for, and stderr is a terminal."""
    try:
        return enabled and sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stderr
        return False


def format_stats(name: str, stats: dict) -> str:
    mirror = stats.get("mirror_by_depth", [])
    per_depth = " + ".join(str(n) for n in mirror) if mirror else "0"
    kind = stats.get("environment_kind") or "none"
    lines = [f"{name}: traced",
             f"  camera rays        {stats.get('camera', 0)}",
             f"  shadow rays        {stats.get('shadow', 0)}",
             f"  mirror rays        {sum(mirror)} (by depth: {per_depth})",
             f"  environment ({kind}) lookups {stats.get('environment', 0)}",
             f"  AOVs               {', '.join(stats.get('aovs', [])) or 'none'}"]
    if "kernels" in stats:
        lines.append(f"  kernels launched   {stats['kernels']}")
    return "\n".join(lines)


class RenderProgress:
    """Context manager around a batch of renders; ``done`` prints one line a job."""

    def __init__(self, total: int, enabled: bool = True):
        self.total, self.enabled = total, enabled
        self.bars = bars_wanted(enabled)
        self.jobs: tqdm | None = None

    def __enter__(self) -> RenderProgress:
        # Mitsuba's messages go through tqdm (and the known-noisy ones nowhere)
        self.logger = mi.logger()
        self.level = self.logger.log_level()
        self.appenders = [self.logger.appender(i) for i in range(self.logger.appender_count())]
        self.logger.clear_appenders()
        self.logger.add_appender(_TqdmAppender(bars=self.bars, warnings=self.enabled))
        if self.bars:
            self.logger.set_log_level(mi.LogLevel.Info)  # progress reports need Info
            if self.total > 1:
                self.jobs = tqdm(total=self.total, desc="scenes", unit="scene", delay=1.0, leave=False,
                                 file=sys.stderr)
        return self

    def done(self, job, variant: str, seconds: dict[str, float], written, stats: dict | None = None) -> None:
        if stats:  # asked for explicitly: shown even with --quiet
            tqdm.write(format_stats(printable(job.scene.name), stats), file=sys.stdout)
        if not self.enabled:
            return
        files = " ".join(printable(p) for p in written)
        # one line a scene, on stdout; tqdm.write lifts the bars (stderr) out of its way
        tqdm.write(f"{printable(job.scene.name)}: {job.width}x{job.height} {variant}, render {seconds['render']:.3f} s "
                   f"(load {seconds['load']:.3f} s, write {seconds.get('write', 0.0):.3f} s) -> {files}",
                   file=sys.stdout)
        if self.jobs is not None:
            self.jobs.update(1)

    def __exit__(self, *exc) -> None:
        if self.jobs is not None:
            self.jobs.close()
        self.logger.clear_appenders()
        for appender in self.appenders:
            self.logger.add_appender(appender)
        self.logger.set_log_level(self.level)
