"""Topic contracts: one declaration per topic, and docs/architecture.md's tables rendered from them."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from fleetslam import topics
from fleetslam.msg.typesys import get_type

DOC = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"
BLOCK = re.compile(r"(<!-- topics: (agent|fleet) [^>]*-->\n)(.*?)(<!-- end topics -->)", re.S)
TABLES = {"agent": topics.AGENT_TOPICS, "fleet": topics.FLEET_TOPICS}


def _rendered(text: str) -> str:
    return BLOCK.sub(lambda m: m.group(1) + topics.markdown_table(TABLES[m.group(2)]) + m.group(4), text)


def test_architecture_doc_shows_the_contracts() -> None:
    """Fails when docs/architecture.md's topic tables differ from the contracts (FLEETSLAM_UPDATE_DOCS=1 rewrites
    them)."""
    text = DOC.read_text(encoding="utf-8")
    assert sorted(m.group(2) for m in BLOCK.finditer(text)) == ["agent", "fleet"]
    expected = _rendered(text)
    if os.environ.get("FLEETSLAM_UPDATE_DOCS") == "1":
        DOC.write_text(expected, encoding="utf-8")
    assert text == expected, (
        "docs/architecture.md's topic tables are stale: run FLEETSLAM_UPDATE_DOCS=1 pytest " + __file__
    )


def test_every_contract_names_a_known_type_once() -> None:
    every = [*topics.AGENT_TOPICS, *topics.FLEET_TOPICS]
    assert len({(t.name, t.type) for t in every}) == len(every)
    assert all(t.name.startswith("/") for t in topics.FLEET_TOPICS)
    assert not any(t.name.startswith("/") for t in topics.AGENT_TOPICS)
    for topic in every:
        get_type(topic.type)  # raises MessageError for an unknown type


def test_subscribers_get_the_publishers_durability() -> None:
    graph = topics.GRAPH.qos(depth=7)
    assert (graph.durability, graph.reliability, graph.depth) == ("transient_local", "reliable", 7)
    assert topics.GRAPH.qos().depth == 1
    image = topics.RGB_IMAGE.qos(depth=1, best_effort=True)
    assert (image.durability, image.reliability) == ("volatile", "best_effort")
    assert topics.GRAPH.of("c3po") == "/c3po/graph" and topics.STATISTICS.of("c3po") == "/statistics"


@pytest.mark.parametrize("module", ["fleetslam.topics"])
def test_contracts_import_without_the_middleware(module: str) -> None:
    script = f"import sys, {module}\nassert 'zenoh' not in sys.modules and 'fleetslam.middleware' not in sys.modules"
    subprocess.run([sys.executable, "-c", script], check=True, timeout=60)
