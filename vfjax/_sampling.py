"""How a recording samples the model: frame rate, frames, RK4 steps, warm-up, time shifts."""

import math

import equinox as eqx

#: Default number of RK4 steps per camera frame: the coarsest step whose GAW keeps NMSE < 1e-4
#: against a 1024-steps-per-frame reference on every set of `benchmarks/accuracy.py` (worst
#: 3.2e-6) *and* whose derivatives stay close to those of the continuous model at the paper's
#: grazing closures. With located events RK4 converges at 4th order; 3 steps a frame pass the
#: first test (2.9e-5), but N1's d GAW / d K is then 10 % off the derivative at 256 steps a
#: frame, against 2.3 % at 4 and 0.4 % at 6 (at every step the derivative is that of the
#: computed GAW, equal to its central differences within 1e-5).
DEFAULT_SUBSTEPS = 4

#: The RK4 step (s) of a default sampling, at most: `DEFAULT_SUBSTEPS` steps a frame at 4 kHz,
#: the frame rate at which that default was chosen. A camera of another rate gets as many
#: steps a frame as keep the step within it (`default_substeps`): at 2 kHz, 4 steps a frame
#: (125 us) simulate the N1 and N3 presets qualitatively wrong (no closed phase, a GAW at
#: twice the frequency: NMSE 2.6 and 2.0 against 64 steps a frame), where 8 (62.5 us) leave
#: 4.9e-6 and 1.9e-7; at 8 and 16 kHz, 2 steps and 1 a frame simulate the presets' +-80 %
#: boxes as 4 do at 4 kHz (the step sets the error, not the frames it holds).
MAX_DEFAULT_STEP = 1.0 / 16000.0

#: The shortest length bucket (frames): recordings of up to this many frames share a program.
_MIN_BUCKET = 128


def default_substeps(fps: float) -> int:
    """RK4 steps per frame by default for a camera at ``fps`` (Hz): the fewest that keep the
    step within `MAX_DEFAULT_STEP` (1/16 000 s), the step of `DEFAULT_SUBSTEPS` at 4 kHz: 8
    at 2 kHz, 6 at 3 kHz, 4 at 4 and 5 kHz, 3 at 6 kHz, 2 at 8-10 kHz, 1 from 16 kHz. At 2
    kHz, 4 steps a frame simulate the N1 and N3 presets without their closed phase; at 8 kHz
    4 steps a frame would cost twice the simulation of 2 for no accuracy the fit needs."""
    return max(1, math.ceil(1.0 / (float(fps) * MAX_DEFAULT_STEP) - 1e-9))


def length_bucket(n_frames: int) -> int:
    """The frame count a recording of ``n_frames`` frames is padded to in a compiled fit: the
    next power of two, at least 128. Recordings whose counts share a bucket share a program."""
    return max(_MIN_BUCKET, 1 << max(int(n_frames) - 1, 0).bit_length())


class Sampling(eqx.Module):
    """How the camera samples a simulation: frames at ``warmup + time_shift + k / fps``.

    The model starts from rest at contact at time 0 and runs ``warmup`` seconds towards its
    limit cycle before the first frame; a fit then moves the frames by a fitted time shift in
    [0, ``max_time_shift``] (the recording starts at an arbitrary point of the cycle). Only
    the frame count sizes a compiled fit (`length_bucket`), and the steps a frame where more
    than 8 (a camera slower than 2 kHz): a new frame rate, warm-up or shift range reuses the
    program.

    Attributes:
        fps: camera frame rate (Hz).
        n_frames: number of frames.
        substeps: RK4 steps per frame (the step is 1 / (substeps fps) s); default
            `default_substeps` of ``fps``.
        warmup: simulated time before the first frame (s).
        max_time_shift: the largest time shift of the frames (s).
    """

    fps: float = eqx.field(converter=float)
    n_frames: int = eqx.field(converter=int)
    substeps: int | None = None
    warmup: float = eqx.field(default=0.0, converter=float)
    max_time_shift: float = eqx.field(default=0.0, converter=float)

    def __post_init__(self):
        if self.substeps is not None:
            self.substeps = int(self.substeps)
        elif math.isfinite(self.fps) and self.fps > 0:  # else `__check_init__` refuses the rate
            self.substeps = default_substeps(self.fps)

    def __check_init__(self):
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"Sampling: fps must be a finite frame rate > 0 Hz, got {self.fps}")
        if self.n_frames < 1 or self.substeps < 1:
            raise ValueError(
                f"Sampling: n_frames and substeps must be >= 1, got {self.n_frames} and "
                f"{self.substeps}"
            )
        for name in ("warmup", "max_time_shift"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"Sampling: {name} must be a finite time >= 0 s, got {value}")

    @property
    def step(self) -> float:
        """The RK4 step (s)."""
        return 1.0 / (self.substeps * self.fps)

    @property
    def duration(self) -> float:
        """Time (s) from the first to the last frame."""
        return (self.n_frames - 1) / self.fps

    @property
    def horizon(self) -> float:
        """The last time (s) a frame may fall at: warm-up, largest shift, recording."""
        return self.warmup + self.max_time_shift + self.duration

    @property
    def shift_frames(self) -> int:
        """Frames spanned by the time-shift range (rounded up)."""
        return math.ceil(self.max_time_shift * self.fps - 1e-9)

    def to_dict(self) -> dict:
        """The fields by name (for JSON)."""
        return {
            "fps": self.fps,
            "n_frames": self.n_frames,
            "substeps": self.substeps,
            "warmup": self.warmup,
            "max_time_shift": self.max_time_shift,
        }
