"""What an absolute path of one machine looks like in a tracked file (issue 53): the pattern that
tests/test_portable_paths.py and the committed-scores tests share."""
import re

MACHINE_PATH = re.compile(r"(^|[\s'\"(=`:-])/(work|home|root|Users)/")  # '-': a shell default ${X:-/path}
