"""Entry point of a reader child started as a fresh interpreter (:mod:`geometry.cad_child`, when it cannot
fork): ``python -m geometry.cad_reader_main PATH TARGET ERROR TOLERANCE_MM ANGULAR_DEG SPLIT MEMORY_MB``."""
import sys

from geometry.cad_child import _child
from geometry.io import tessellate_cad_here

if __name__ == "__main__":
    path, target, error, tolerance, angular, split, memory = sys.argv[1:8]
    _child(tessellate_cad_here, path, target, error, float(tolerance), float(angular), split == "1", int(memory))
