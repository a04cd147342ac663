"""What a run of the main job did (``ShotProcessor.run``), as printed and as ``--json``."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class ProcessSummary:
    """What a run did: roles, lights, frames, per-stage seconds, output files and sizes."""

    input: str
    output: str
    roles: list
    lights: list
    frames: list
    timings: dict
    warnings: list
    output_bytes: int = 0
    probe_files: int = 0
    samples_written: int = 0
    affected: dict = field(default_factory=dict)

    @property
    def seconds(self) -> float:
        """Wall seconds of the whole run."""
        return float(self.timings.get("total", 0.0))

    def as_dict(self) -> dict:
        frame_time = self.timings.get("frames", 0.0)
        return {
            "input": self.input, "output": self.output,
            "roles": [{"path": r.path, "role": r.role, "from": r.source, "dynamic": r.dynamic,
                       "casts_shadows": r.casts_shadows, "receives_shadows": r.receives_shadows,
                       "relight": r.relight} for r in self.roles],
            "lights": [{"name": lt.name, "kind": lt.kind, "position": [float(x) for x in lt.position],
                        "direction": [float(x) for x in lt.direction], "color": [float(x) for x in lt.color],
                        "intensity": float(lt.intensity), "score": lt.score, "source": lt.source}
                       for lt in self.lights],
            "frames": {"count": len(self.frames), "first": self.frames[0] if self.frames else None,
                       "last": self.frames[-1] if self.frames else None},
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
            "seconds_per_frame": round(frame_time / max(len(self.frames), 1), 4),
            "frames_per_second": round(len(self.frames) / frame_time, 3) if frame_time > 0 else None,
            "output_bytes": self.output_bytes, "probe_files": self.probe_files,
            "samples_written": self.samples_written, "affected_frames": self.affected,
            "warnings": self.warnings,
        }
