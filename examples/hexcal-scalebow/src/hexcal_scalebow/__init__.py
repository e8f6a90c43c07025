"""hexcal-scalebow: the ``scalebow`` effect for hexcal (an encoder scale error quadratic along
the stroke), an example of an effect package. Installing it is all it takes: hexcal loads it
through its entry point in the group ``hexcal.effects`` (pyproject.toml)."""

from hexcal_scalebow.effect import ScaleBow

__version__ = "0.1.0"
__all__ = ["ScaleBow", "__version__"]
