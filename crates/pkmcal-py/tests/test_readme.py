"""The README's Python session and the package docstring run as written."""

import doctest
import re

import pkmcal
from conftest import REPO


def test_readme_session():
    text = (REPO / "README.md").read_text()
    section = text.split("\n## Python\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert blocks, "the README's Python section has a session"
    parser = doctest.DocTestParser()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for block in blocks:
        # Comments after a statement are for the reader.
        test = parser.get_doctest(block, {}, "README", "README.md", 0)
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0 and result.attempted > 5


def test_package_docstring():
    result = doctest.testmod(pkmcal, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted > 0
