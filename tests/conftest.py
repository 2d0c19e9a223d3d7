import sys
from pathlib import Path

# tests/helpers.py and tests/reference.py are imported by name from every tier
sys.path.insert(0, str(Path(__file__).parent))
