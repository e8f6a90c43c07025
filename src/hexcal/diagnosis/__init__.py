"""Compare the model with the measurements, find where it fails and which effect is missing.

The flow (a library; the CLI and the text UI sit on top): :func:`fit_model` fits the geometry
with a set of effects; :func:`diagnose` judges it against the noise floor on held-out poses,
ranks every catalogue effect not in the model, and gives a verdict.
"""

from hexcal.diagnosis.diagnose import Candidate, Diagnosis, diagnose
from hexcal.estimate.effect_fit import ModelFit, fit_model

__all__ = ["Candidate", "Diagnosis", "ModelFit", "diagnose", "fit_model"]
