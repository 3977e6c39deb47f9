"""The viser port is no back door: Origin check, operator token, validated GUI values.

The service runs for real (``create_app`` in a ``TestClient``, viser on a free port, a tiny
step source); the "browser" is a raw WebSocket client speaking viser's wire protocol
(msgpack messages in, zstd-framed msgpack batches out), so it can send what no slider would:
clicks on disabled buttons, out-of-range values, strings, NaN, property changes.
"""

from __future__ import annotations

import gc
import logging
import math
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import msgspec
import pytest
import viser
import zstandard
from fastapi.testclient import TestClient
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect
from websockets.typing import Origin, Subprotocol

from app.server.main import create_app
from app.service.settings import Settings
from app.sim.sim_config import SimConfig
from app.viz.access import AccessPolicy, OriginPolicy
from app.viz.gui import DockingGui
from tests.support.fake_sim import FakeSimState
from tests.support.inline_sim import inline_sim
from tests.support.waiting import wait_until

TOKEN = "s3cret-operator-token"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Source:
    """Cheapest step source: the loop publishes a record per tick, nothing else."""

    def __init__(self, config: SimConfig, calibration: object) -> None:
        self.k = 0

    @property
    def done(self) -> bool:
        return False

    def step(self) -> Any:
        self.k += 1
        return FakeSimState(t_s=self.k / 30.0)


@contextmanager
def _service(tmp_path: Path, token: str | None) -> Iterator[Any]:
    settings = Settings(
        host="127.0.0.1",
        port=_free_port(),
        viser_port=_free_port(),
        token=token,
        recordings_dir=tmp_path / "rec",
        sim_autostart=False,
        sim_auto_restart_s=None,
        tick_hz=30.0,
    )
    with TestClient(create_app(settings, source_factory=inline_sim(_Source))) as http:
        state = http.app.state.aar  # type: ignore[attr-defined]
        assert state.viz is not None and state.viser_port
        yield state


def _decode(frame: bytes) -> list[dict[str, Any]]:
    """One server->client frame: [u64 size][u64 zstd size][zstd msgpack][binary buffers]."""
    size = int.from_bytes(frame[:8], "little")
    zsize = int.from_bytes(frame[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(frame[16 : 16 + zsize], max_output_size=size)
    return list(msgspec.msgpack.decode(inner)["messages"])


class Wire:
    """A raw viser client over a real WebSocket."""

    def __init__(self, port: int, origin: str | None) -> None:
        self.ws = connect(
            f"ws://127.0.0.1:{port}",
            subprotocols=[Subprotocol(f"viser-v{viser.__version__}")],
            origin=Origin(origin) if origin else None,
            open_timeout=10,
            max_size=None,
        )
        self.messages: list[dict[str, Any]] = []
        self.closed = threading.Event()
        self._lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        try:
            for frame in self.ws:
                if isinstance(frame, bytes):
                    batch = _decode(frame)
                    with self._lock:
                        self.messages.extend(batch)
        except ConnectionClosed:
            pass
        finally:
            self.closed.set()

    def send(self, message: dict[str, Any]) -> None:
        self.ws.send(msgspec.msgpack.encode(message))

    def camera(self) -> None:
        """What a browser sends first; viser registers the client (and our panel) on it."""
        self.send(
            {
                "type": "ViewerCameraMessage",
                "wxyz": [1.0, 0.0, 0.0, 0.0],
                "position": [0.0, 0.0, 0.0],
                "fov": 1.0,
                "near": 0.01,
                "far": 100.0,
                "image_height": 480,
                "image_width": 640,
                "look_at": [0.0, 0.0, 1.0],
                "up_direction": [0.0, 0.0, -1.0],
            }
        )

    def widget(self, label: str, timeout: float = 10.0) -> dict[str, Any]:
        """The creation message of the widget with this label (waits for it)."""
        found: list[dict[str, Any]] = []

        def look() -> bool:
            with self._lock:
                found[:] = [
                    m
                    for m in self.messages
                    if m["type"].startswith("Gui") and (m.get("props") or {}).get("label") == label
                ]
            return bool(found)

        wait_until(look, timeout, f"widget {label!r}")
        return found[-1]

    def uuid(self, label: str) -> str:
        return str(self.widget(label)["uuid"])

    def set(self, label: str, value: Any, prop: str = "value") -> None:
        self.send({"type": "GuiUpdateMessage", "uuid": self.uuid(label), "updates": {prop: value}})

    def click(self, label: str) -> None:
        self.set(label, True)

    def updates(self, label: str) -> list[dict[str, Any]]:
        """GUI property updates the server sent this client for that widget."""
        uuid = self.uuid(label)
        with self._lock:
            return [
                m["updates"]
                for m in self.messages
                if m["type"] == "GuiUpdateMessage" and m["uuid"] == uuid
            ]

    def last(self, label: str) -> dict[str, Any] | None:
        """The latest update of that widget's value the server sent (None: none yet)."""
        values = [u for u in self.updates(label) if "value" in u]
        return values[-1] if values else None

    def close(self) -> None:
        self.ws.close()


@contextmanager
def _wire(state: Any, origin: str | None = "same") -> Iterator[Wire]:
    port = state.viser_port
    w = Wire(port, f"http://127.0.0.1:{port}" if origin == "same" else origin)
    try:
        yield w
    finally:
        w.close()


def _panel_id(gui: DockingGui, known: set[int] = frozenset()) -> int:  # type: ignore[assignment]
    ids: list[int] = []

    def look() -> bool:
        ids[:] = [i for i in gui._panels if i not in known]
        return bool(ids)

    wait_until(look, what="the client's panel")
    return ids[0]


def _refusals(gui: DockingGui, before: int, n: int) -> None:
    """Barrier: the server has refused ``n`` more GUI messages (then give stragglers 0.2 s)."""
    wait_until(
        lambda: gui.rejected >= before + n, what=f"{n} refusals (got {gui.rejected - before})"
    )
    time.sleep(0.2)


ATTACK = [
    ("Start", True),
    ("Reset", True),
    ("Clutter lights", 50),
    ("Clutter lights", 5),
    ("Noise σ (DN)", 45.0),
    ("Turbulence", "severe"),
    ("LED 1 off", True),
    ("Closure (m/s)", 2.0),
]


def test_with_token_a_client_watches_until_it_enters_the_operator_token(tmp_path: Path) -> None:
    with _service(tmp_path, TOKEN) as st, _wire(st) as w, _wire(st) as bystander:
        gui = st.viz.gui
        cfg0, run0 = st.loop.config, st.loop.run
        w.camera()
        cid = _panel_id(gui)
        bystander.camera()
        other = _panel_id(gui, {cid})
        # the controls arrive disabled, with the token field and Unlock
        assert w.widget("Start")["props"]["disabled"] is True
        assert w.widget("Clutter lights")["props"]["disabled"] is True
        assert w.widget("Operator token")["props"]["disabled"] is False
        # raw messages that a disabled widget would never send: all refused
        before = gui.rejected
        for label, value in ATTACK:
            w.set(label, value)
        w.set("Start", False, prop="disabled")  # re-enable it from the client side
        _refusals(gui, before, len(ATTACK) + 1)
        assert st.loop.running is False and st.loop.run == run0
        assert st.loop.config == cfg0
        panel = gui.panel(cid)
        assert panel is not None and panel.buttons["start"].disabled is True
        assert panel.clutter.value == cfg0.clutter and panel.noise.value == cfg0.noise_sigma
        # and the sender's own widgets are put back (viser's slider number box stays editable)
        wait_until(lambda: w.last("Clutter lights") == {"value": cfg0.clutter})
        wait_until(lambda: w.last("Turbulence") == {"value": cfg0.turbulence})

        # a wrong token unlocks nothing
        w.set("Operator token", "guess")
        before = gui.rejected
        w.click("Unlock")
        _refusals(gui, before, 1)
        assert not st.viz.policy.is_operator(cid)
        w.click("Start")
        _refusals(gui, before + 1, 1)
        assert st.loop.running is False

        # the right one unlocks this client's controls (and only this client's)
        w.set("Operator token", TOKEN)
        w.click("Unlock")
        wait_until(lambda: st.viz.policy.is_operator(cid), what="unlock")
        wait_until(lambda: {"disabled": False} in w.updates("Start"), what="Start enabled")
        assert panel.token.value == ""  # the field is cleared
        w.click("Start")
        wait_until(lambda: st.loop.running, what="start")
        w.set("Clutter lights", 7)
        w.set("LED 2 off", True)
        wait_until(lambda: st.loop.config.clutter == 7 and st.loop.config.led_dropout == [2])
        assert st.loop.run > run0
        # the other tab saw the change but still may not make one
        wait_until(
            lambda: {"value": 7} in bystander.updates("Clutter lights"), what="bystander sync"
        )
        assert not st.viz.policy.may_control(other)
        before = gui.rejected
        bystander.click("Stop")
        bystander.set("Clutter lights", 3)
        _refusals(gui, before, 2)
        assert st.loop.running is True and st.loop.config.clutter == 7

        # even an operator gets no value beyond the widget's range; the widget is re-synced
        before = gui.rejected
        w.set("Noise σ (DN)", 45.0)
        _refusals(gui, before, 1)
        assert st.loop.config.noise_sigma == cfg0.noise_sigma
        assert panel.noise.value == cfg0.noise_sigma
        wait_until(lambda: w.last("Noise σ (DN)") == {"value": cfg0.noise_sigma})


def test_with_token_the_share_url_tunnel_needs_the_operator(tmp_path: Path) -> None:
    with _service(tmp_path, TOKEN) as st, _wire(st) as w:
        calls: list[int] = []
        st.viz.server.request_share_url = lambda *a, **k: calls.append(1)
        w.camera()
        cid = _panel_id(st.viz.gui)
        w.send({"type": "ShareUrlRequest"})
        w.camera()  # processed after it, in order
        time.sleep(0.3)
        assert calls == []
        w.set("Operator token", TOKEN)
        w.click("Unlock")
        wait_until(lambda: st.viz.policy.is_operator(cid), what="unlock")
        w.send({"type": "ShareUrlRequest"})
        wait_until(lambda: calls == [1], what="share request of the operator")


def test_without_token_valid_changes_apply_and_out_of_range_ones_are_refused(
    tmp_path: Path,
) -> None:
    with _service(tmp_path, None) as st, _wire(st) as w:
        gui = st.viz.gui
        w.camera()
        cid = _panel_id(gui)
        panel = gui.panel(cid)
        assert panel is not None and panel.token is None
        assert w.widget("Start")["props"]["disabled"] is False
        w.click("Start")
        wait_until(lambda: st.loop.running, what="start")
        w.set("Clutter lights", 5)
        w.set("Turbulence", "severe")
        wait_until(lambda: st.loop.config.clutter == 5 and st.loop.config.turbulence == "severe")
        cfg = st.loop.config
        before = gui.rejected
        w.set("Noise σ (DN)", 45.0)  # SimConfig would take 45; the slider stops at 20
        w.set("Clutter lights", 50)
        _refusals(gui, before, 2)
        assert st.loop.config == cfg
        assert panel.noise.value == cfg.noise_sigma and panel.clutter.value == 5
        wait_until(lambda: w.last("Noise σ (DN)") == {"value": cfg.noise_sigma})
        wait_until(lambda: w.last("Clutter lights") == {"value": 5})


JUNK: list[tuple[str, Any]] = [
    ("Noise σ (DN)", math.nan),
    ("Noise σ (DN)", math.inf),
    ("Noise σ (DN)", "abc"),
    ("Noise σ (DN)", None),
    ("Noise σ (DN)", [1, 2]),
    ("Noise σ (DN)", 1e308),
    ("Clutter lights", 2**62),
    ("Clutter lights", 2.5),
    ("Clutter lights", True),
    ("Closure (m/s)", -1.0),
    ("Turbulence", "hurricane"),
    ("Turbulence", 3),
    ("LED 1 off", "yes"),
    ("LED 1 off", 1),
    ("Start", "now"),
]


def test_junk_from_the_wire_raises_nothing_and_changes_nothing(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    with _service(tmp_path, None) as st, _wire(st) as w:
        gui = st.viz.gui
        w.camera()
        cid = _panel_id(gui)
        cfg0, run0 = st.loop.config, st.loop.run
        capfd.readouterr()
        caplog.clear()
        caplog.set_level(logging.WARNING)
        before = gui.rejected
        for label, value in JUNK:
            w.set(label, value)
        w.set("Clutter lights", 3, prop="max")  # property changes are not the client's
        w.send({"type": "GuiUpdateMessage", "uuid": w.uuid("Noise σ (DN)"), "updates": {}})
        _refusals(gui, before, len(JUNK) + 2)
        gc.collect()  # an unretrieved task exception is reported when the task is collected
        time.sleep(0.2)
        assert st.loop.config == cfg0 and st.loop.run == run0 and st.loop.running is False
        panel = gui.panel(cid)
        assert panel is not None
        assert panel.noise.value == cfg0.noise_sigma and panel.clutter.value == cfg0.clutter
        assert panel.turbulence.value == cfg0.turbulence and panel.dropout[0].value is False
        assert panel.clutter.max == 20
        err = capfd.readouterr().err
        assert "Traceback" not in err and "exception" not in err.lower(), err
        bad = [r for r in caplog.records if r.levelno >= logging.ERROR or r.name == "asyncio"]
        assert bad == [], [r.getMessage() for r in bad]
        # and the connection still works
        w.set("Clutter lights", 4)
        wait_until(lambda: st.loop.config.clutter == 4)


def test_the_callbacks_themselves_refuse_junk_without_raising(tmp_path: Path) -> None:
    """Behind the message gate: the callbacks re-check everything (defence in depth)."""
    with _service(tmp_path, TOKEN) as st, _wire(st) as w:
        gui = st.viz.gui
        w.camera()
        cid = _panel_id(gui)
        panel = gui.panel(cid)
        assert panel is not None
        cfg0 = st.loop.config

        def noise(client_id: int, value: Any) -> None:
            gui.handle_change(panel, "noise_sigma", client_id, value)

        def clutter(client_id: int, value: Any) -> None:
            gui.handle_change(panel, "clutter", client_id, value)

        # not an operator yet: even a valid value is refused
        clutter(cid, 3)
        gui.handle_change(panel, "start", cid, True)
        assert st.loop.config == cfg0 and st.loop.running is False
        st.viz.policy.grant(cid)
        for value in (math.nan, "abc", 1e300, -1.0, None, 45.0, [1], {"a": 1}):
            noise(cid, value)  # must not raise
        clutter(cid, 10**30)
        clutter(cid, 2.5)
        clutter(cid + 1000, 3)  # an event naming another client
        gui.handle_change(panel, "led1", cid, "yes")
        gui.handle_change(panel, "turbulence", cid, "hurricane")
        assert st.loop.config == cfg0
        assert panel.noise.value == cfg0.noise_sigma
        with pytest.raises(ValueError):
            gui.candidate("noise_sigma", math.nan)
        clutter(cid, 3)
        assert st.loop.config.clutter == 3 and panel.clutter.value == 3


def test_a_foreign_origin_is_refused_at_the_handshake(tmp_path: Path) -> None:
    with _service(tmp_path, None) as st:
        evil = Wire(st.viser_port, "http://evil.example")
        try:
            with suppress(ConnectionClosed):  # the server may close it before these go out
                evil.camera()
                evil.send({"type": "ShareUrlRequest"})
            assert evil.closed.wait(10), "the connection was not closed"
            assert evil.ws.close_code == 1008
        finally:
            evil.close()
        time.sleep(0.3)
        assert st.viz.gui._panels == {} and st.viz.server.get_clients() == {}
        with _wire(st) as ok, _wire(st, origin=None) as tool:
            ok.camera()
            tool.camera()
            wait_until(lambda: len(st.viz.gui._panels) == 2, what="two panels")
            assert not ok.closed.is_set() and not tool.closed.is_set()


def test_origin_policy() -> None:
    settings = Settings(
        host="0.0.0.0", port=8000, viser_port=8080, public_viser_url="https://aar.example/3d/"
    )
    p = AccessPolicy.from_settings(settings, viser_port=8080)
    ok = p.origin_allowed
    assert ok(None, "127.0.0.1:8080")  # not a browser
    assert ok("http://127.0.0.1:8080", "127.0.0.1:8080")  # the viser page itself
    assert ok("http://localhost:8000", "localhost:8080")  # the FastAPI page, same host
    assert ok("http://[::1]:8080", "[::1]:8080")
    assert ok("http://192.168.1.7:8080", "192.168.1.7:8080")
    assert ok("https://aar.example", "10.0.0.2:8080")  # public_viser_url (reverse proxy)
    assert not ok("http://evil.example", "127.0.0.1:8080")
    assert not ok("http://evil.example:8080", "evil.example:8080")  # DNS rebinding
    assert not ok("http://127.0.0.1:9999", "127.0.0.1:8080")  # another local app
    assert not ok("http://192.168.1.9:8080", "192.168.1.7:8080")  # another machine
    assert not ok("null", "127.0.0.1:8080")
    assert not ok("file://", "127.0.0.1:8080")
    assert not ok("http://127.0.0.1:8080", None)
    named = OriginPolicy(ports=[8080], names=["groundstation"])
    assert named.allows("http://groundstation:8080", "groundstation:8080")
    assert not named.allows("http://other:8080", "other:8080")
    # the REST guard's settings, where present: AAR_TRUSTED_HOSTS, AAR_ALLOWED_ORIGINS
    hardened = SimpleNamespace(
        token=None,
        host="0.0.0.0",
        port=8000,
        trusted_hosts=["*.ops.example", "gs1"],
        allowed_origins=["https://console.example:8443"],
    )
    q = AccessPolicy.from_settings(hardened, viser_port=8080).origin_allowed
    assert q("http://a.ops.example:8080", "a.ops.example:8080")
    assert q("http://gs1:8080", "gs1:8080")
    assert q("https://console.example:8443", "10.0.0.2:8080")
    assert not q("http://evil.example:8080", "evil.example:8080")
    assert not q("https://console.example", "10.0.0.2:8080")  # another port
    assert AccessPolicy(TOKEN).check_token(TOKEN)
    for wrong in ("", "s3cret", TOKEN + "x", "é" * 3, None, 42, "x" * 5000):
        assert not AccessPolicy(TOKEN).check_token(wrong)


CHROMIUM = "/usr/bin/chromium"


@pytest.mark.browser
def test_in_a_real_browser_a_locked_tab_is_read_only_until_unlocked(tmp_path: Path) -> None:
    """Chromium on the viser page: what the operator sees and what the server keeps."""
    assert Path(CHROMIUM).exists(), "chromium missing at /usr/bin/chromium"
    from playwright.sync_api import sync_playwright

    args = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run"]
    with _service(tmp_path, TOKEN) as st, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=args)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.goto(f"http://127.0.0.1:{st.viser_port}/")  # the page's own Origin: accepted
            start = page.get_by_role("button", name="Start")
            start.wait_for(timeout=60_000)
            assert start.is_disabled()
            # viser leaves a disabled slider's number box editable: typed values are refused
            # and the box is put back
            boxes = page.locator("input.mantine-NumberInput-input")
            assert boxes.count() == 3
            boxes.nth(2).fill("7")
            wait_until(lambda: boxes.nth(2).input_value() == "0", what="locked box put back")
            assert st.loop.config.clutter == 0
            token = page.get_by_role("textbox").first
            token.fill("wrong")
            page.get_by_role("button", name="Unlock").click()
            page.wait_for_timeout(500)
            assert start.is_disabled() and st.viz.policy._operators == set()
            token.fill(TOKEN)
            page.get_by_role("button", name="Unlock").click()
            wait_until(lambda: not start.is_disabled(), what="unlocked")
            start.click()
            wait_until(lambda: st.loop.running, what="start from the browser")
            boxes.nth(1).fill("45")  # noise: beyond the slider
            wait_until(lambda: boxes.nth(1).input_value() == "2", what="noise box put back")
            boxes.nth(2).fill("6")
            wait_until(lambda: st.loop.config.clutter == 6, what="clutter from the browser")
            assert st.loop.config.noise_sigma == 2.0
        finally:
            browser.close()
