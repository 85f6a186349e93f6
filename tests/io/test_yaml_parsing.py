"""parse_yaml keeps what it parsed by its text: the same text is composed once (a noise model
read once per exposure), each caller gets its own copy, PyYAML's own document, and an edited
file is read anew."""

import pytest
import yaml

from spherex_reduce.core.errors import ConfigError
from spherex_reduce.io.config import PARSED_DOCUMENTS, load_yaml, parse_yaml

TEXT = """\
noise:
  components:
    - {name: channel, alpha: 2.0e-3, beta: &b 1.5e-2, gamma: 0.0}
    - {name: common, alpha: 1.0e-4, beta: *b}
unit: adu
gain: 1.3
"""


def _composes(monkeypatch):
    count = []
    compose = yaml.SafeLoader.get_single_node
    monkeypatch.setattr(yaml.SafeLoader, "get_single_node",
                        lambda self: (count.append(1), compose(self))[1])
    return count


def test_the_same_text_is_composed_once_and_each_caller_gets_its_own_document(monkeypatch):
    text = TEXT + "# parsed once\n"  # a text no other test parses
    expected = yaml.safe_load(text)
    count = _composes(monkeypatch)
    first = parse_yaml(text)
    assert first == expected
    first["noise"]["components"][0]["alpha"] = -1.0  # a caller changing what it was given
    second = parse_yaml(text)
    assert second == expected and second is not first
    assert len(count) == 1


def test_an_edited_file_is_read_anew_and_an_error_is_raised_each_time(tmp_path):
    path = tmp_path / "model.yaml"
    path.write_text(TEXT)
    assert load_yaml(path)[0]["gain"] == 1.3
    path.write_text(TEXT.replace("gain: 1.3", "gain: 2.6"))  # same size, same name
    assert load_yaml(path)[0]["gain"] == 2.6
    for _ in range(2):
        with pytest.raises(ConfigError, match="appears twice"):
            parse_yaml("gain: 1\ngain: 2\n", "dup.yaml")


def test_the_documents_kept_are_bounded_in_number(monkeypatch):
    """A stream of distinct texts keeps at most PARSED_DOCUMENTS of them: the oldest is
    parsed again, the newest is not."""
    texts = [f"bound_{i}: {i}\n" for i in range(PARSED_DOCUMENTS + 1)]
    for text in texts:
        parse_yaml(text)
    count = _composes(monkeypatch)
    assert parse_yaml(texts[-1]) == {f"bound_{PARSED_DOCUMENTS}": PARSED_DOCUMENTS}
    assert len(count) == 0
    assert parse_yaml(texts[0]) == {"bound_0": 0}
    assert len(count) == 1
