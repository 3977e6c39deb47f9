"""/metrics read back by a parser we did not write (prometheus_client's text parser)."""

from __future__ import annotations

from types import SimpleNamespace

from prometheus_client.parser import text_string_to_metric_families

from app.service.metrics import render_metrics


class _Streams:
    """The two calls render_metrics makes on the stream service."""

    def __init__(self, source: str) -> None:
        self.source = source

    def health(self) -> SimpleNamespace:
        return SimpleNamespace(source=self.source, status="ok", rate_hz=29.5)

    def status(self) -> dict[str, int]:
        return {"restarts": 2, "consecutive_failures": 0, "rejected": 3}


def test_a_hostile_source_string_is_escaped_and_reads_back() -> None:
    """The ``source`` label is the operator's free text: quotes, backslashes and a newline
    once broke the exposition (hand-written ``{k="v"}``) and could forge a sample."""
    source = 'video:/data/a"b\\c\naar_stream_up{source="x"} 1'
    loop = SimpleNamespace(
        ticks=7, dropped=1, errors=0, tick_rate_hz=lambda: 30.0, config=SimpleNamespace(tick_hz=30)
    )
    bus = SimpleNamespace(stage_quantiles=lambda q: {"step": 1.5 * q})
    text = render_metrics(loop, bus, streams=_Streams(source))  # type: ignore[arg-type]
    families = {f.name: f for f in text_string_to_metric_families(text)}
    up = families["aar_stream_up"].samples
    assert len(up) == 1 and up[0].labels == {"source": source} and up[0].value == 1.0
    assert families["aar_ticks"].samples[0].value == 7.0  # counters: the family without _total
    rejected = families["aar_push_rejected"].samples[0]
    assert rejected.name == "aar_push_rejected_total" and rejected.value == 3.0
    assert families["aar_stream_restarts"].samples[0].labels == {"source": source}
