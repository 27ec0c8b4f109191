"""Fit, diagnose, extend, repeat: the whole loop of `vfjax diagnose` (`vfjax.investigate`).

study = vfjax.investigate(recording)        # the paper's model, then up to 2 effects
study.rounds[0].diagnosis.verdict           # what is missing, in words
study.final.nmse                            # the error after the last extension
study.outcome(recording).words              # explained, unexplained, or at the noise level
vfjax.report.write_report(study, recording, "out/")
"""

from ._diagnosis import EXPLAINED_SHARE, Investigation, Outcome, Round, extend_from, investigate

__all__ = ["EXPLAINED_SHARE", "Investigation", "Outcome", "Round", "extend_from", "investigate"]
