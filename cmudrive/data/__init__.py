"""Training data from expert rollouts (issue 12): language labels (``language``)."""

from cmudrive.data.language import Language, LanguageInputs, describe

__all__ = ["Language", "LanguageInputs", "describe"]
