"""`coopsumo adaptive-fit ROOT` (with --fit) and `coopsumo adaptive ROOT` (without) under their old name (the
studies: coopsumo/studies/adaptive_fit.py and adaptive_alpha.py); kept so that old command lines still work."""

import sys

from coopsumo.studies import adaptive_alpha, adaptive_fit


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if "--fit" in args:
        return adaptive_fit.main([a for a in args if a != "--fit"])
    return adaptive_alpha.main(args)


if __name__ == "__main__":
    sys.exit(main())
