"""The four phases of a glottal cycle, as the model defines them (`MODEL_SPEC.md`).

- opening: x_0 < x <= x_c and v > 0
- open: x > x_c
- closing: x_0 < x <= x_c and v < 0
- closed: x <= x_0, including the closure hold
"""

OPENING, OPEN, CLOSING, CLOSED = 0, 1, 2, 3
#: Phase names indexed by phase code.
PHASE_NAMES = ("opening", "open", "closing", "closed")
#: Colours used to shade phases in figures, indexed by phase code.
PHASE_COLOURS = ("#8ecae6", "#ffffff", "#ffb703", "#adb5bd")
