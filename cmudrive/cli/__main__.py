"""``python -m cmudrive.cli`` (e.g. ``accelerate launch -m cmudrive.cli train ...``)."""

from cmudrive.cli import main

if __name__ == "__main__":
    main()
