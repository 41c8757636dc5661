"""Run the ```python blocks of documentation pages, in order, one Python session per page.

Usage: python .ci/check_docs_code.py docs/tutorial.md [more pages]; exit 1 naming the first block that fails.
"""

import re
import sys
import traceback

BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)

failed = False
for page in sys.argv[1:]:
    text = open(page, encoding="utf-8").read()
    namespace = {"__name__": "__main__"}
    for number, match in enumerate(BLOCK.finditer(text), start=1):
        line = text.count("\n", 0, match.start()) + 1
        try:
            exec(compile(match.group(1), f"{page}:{line}", "exec"), namespace)
        except Exception:
            traceback.print_exc()
            print(f"{page}: block {number} (line {line}) failed", file=sys.stderr)
            failed = True
            break
    else:
        print(f"{page}: {number if text.count('```python') else 0} blocks ran")
sys.exit(1 if failed else 0)
