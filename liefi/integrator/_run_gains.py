"""The gains of a run, replayable as they are: ``FeedbackIntegrator(..., gains=sol.stability.gains)``.

A run may leave invariants out of ``V`` (``drop_exact``: those its scheme keeps exactly,
``sol.dropped``), and then its gains (``sol.stability.gains``, ``final_gains``, the entries of
``gain_history``) have no entry for them.  Given to a constructor as they are, such gains would
miss names; so the run hands them out as :class:`RunGains`, a ``dict`` ``{name: k}`` that also
carries ``dropped`` (``{name: reason}``), and the constructor leaves those invariants out too
(:meth:`~liefi.integrator.feedback.FeedbackIntegrator.without`): the integrator of the run, whose
field and steps are those of the run.
"""

from __future__ import annotations


class RunGains(dict):
    """``{name: k}``, the gains of a run, with ``dropped``: ``{name: reason}``, the invariants it left out of ``V``."""

    def __init__(self, gains=(), dropped=None):
        super().__init__(gains)
        self.dropped = dict(dropped or {})

    def __repr__(self):
        return f"RunGains({dict.__repr__(self)}, dropped={sorted(self.dropped)})" if self.dropped else \
            dict.__repr__(self)


def carry_dropped(report, dropped):
    """Make the gains of a run's ``report`` (:class:`~liefi.integrator.guard.RunReport`) :class:`RunGains`.

    ``dropped``: the run's ``({"name", "reason"}, ...)`` (``sol.dropped``); without any, unchanged.
    """
    drops = {d["name"]: d["reason"] for d in dropped}
    if report is None or not drops:
        return report
    report.gains = RunGains(report.gains, drops)
    report.gain_history = [RunGains(g, drops) for g in report.gain_history]
    return report


def split(gains):
    """``(gains, drops)``: the constructor's ``gains=`` with a placeholder gain for each invariant a run
    dropped (:class:`RunGains`; removed again by :func:`apply`), and those ``{name: reason}``."""
    drops = dict(getattr(gains, "dropped", None) or {})
    if not drops or not isinstance(gains, dict):
        return gains, {}
    return {**dict.fromkeys(drops, 1.0), **gains}, drops


def apply(fi, drops):
    """Leave ``drops`` out of ``V`` of ``fi``, in place, at the end of its construction (as ``fi.without``)."""
    if drops:
        new = fi.without(drops)
        fi.__dict__.clear()
        fi.__dict__.update(new.__dict__)
