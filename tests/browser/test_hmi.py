"""The HMI clicked through in headless Chromium against ``lupin run --sim``.

Every check is judged by the daemon (``/api/state``) or by what the page put on
the wire, never by the page's own idea of what it did.
"""

from __future__ import annotations

import json
import math
import time
import urllib.request
from pathlib import Path
from typing import Any

from browser.harness import (
    LAPTOP,
    PHONE,
    Lupin,
    connected,
    screenshot,
    set_slider,
    start_lupin,
    stop_lupin,
)


def sent(page: Any, kind: str) -> list[dict[str, Any]]:
    frames: list[dict[str, Any]] = page.evaluate(
        f"window.__sent.filter(s => s.frame.type === '{kind}')"
    )
    return frames


def lupin_joint(state: dict[str, Any], name: str) -> dict[str, Any]:
    joint: dict[str, Any] = next(j for j in state["joints"] if j["name"] == name)
    return joint


def wheel_goals(state: dict[str, Any]) -> list[int]:
    return [w["goal_counts_s"] for w in state["base"]["wheels"]]


def text(page: Any, element_id: str) -> str:
    value: str = page.text_content(f"#{element_id}")
    return value


def no_toast(page: Any) -> None:
    toasts = page.locator(".toast[data-tone='bad']").all_text_contents()
    assert not toasts, f"the page reported errors: {toasts}"


def enable_torque(page: Any, lupin: Lupin) -> None:
    page.click("[data-testid=torque-on]")
    page.wait_for_function("document.getElementById('torque-text').textContent === 'on'")
    lupin.wait_for("torque on", lambda s: s["torque"] == "on")


# -- drive ---------------------------------------------------------------------------


def test_drive_pad_streams_at_10hz_while_held_and_goes_silent_on_release(
    open_hmi: Any, lupin: Lupin
) -> None:
    page = open_hmi(LAPTOP)
    box = page.locator("[data-testid=drive-pad]").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(cx, cy)
    page.mouse.down()
    page.mouse.move(cx, cy - box["height"] * 0.35, steps=4)  # forward
    held_at = time.monotonic()
    state = lupin.wait_for(
        "the manual source to drive the wheels",
        lambda s: s["mux"]["active"] == "manual" and any(wheel_goals(s)),
    )
    assert state["base"]["twist"]["linear_x"] > 0
    page.wait_for_function("document.getElementById('mux-active').textContent === 'manual'")
    time.sleep(max(0.0, 1.5 - (time.monotonic() - held_at)))
    released_at = page.evaluate("performance.now()")
    page.mouse.up()
    held_s = time.monotonic() - held_at

    # One zero twist stops the wheels at once ...
    lupin.wait_for("the wheels to stop", lambda s: not any(wheel_goals(s)), timeout=1.0)
    # ... and then silence lets the mux time the source out.
    lupin.wait_for("the manual source to expire", lambda s: s["mux"]["active"] is None, 2.0)
    page.wait_for_function("document.getElementById('mux-active').textContent === 'none'")
    time.sleep(0.5)

    twists = sent(page, "twist")
    assert all(t["frame"]["source"] == "manual" for t in twists)
    after = [t["frame"] for t in twists if t["t"] >= released_at]
    assert len(after) == 1, f"release must send one zero twist and then nothing, sent {after}"
    assert after[0]["linear_x"] == after[0]["linear_y"] == after[0]["angular_z"] == 0
    moving = [t for t in twists if t["frame"]["linear_x"] != 0]
    rate = (len(moving) - 1) / held_s
    assert 7 <= rate <= 12, f"{len(moving)} twists in {held_s:.2f} s is not 10 Hz"
    no_toast(page)


def test_drive_pad_works_by_touch(open_hmi: Any, lupin: Lupin) -> None:
    page = open_hmi(PHONE, has_touch=True, is_mobile=True, device_scale_factor=2)
    pad = page.locator("[data-testid=drive-pad]")
    pad.scroll_into_view_if_needed()
    box = pad.bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    cdp = page.context.new_cdp_session(page)
    point = {"x": cx, "y": cy}
    cdp.send("Input.dispatchTouchEvent", {"type": "touchStart", "touchPoints": [point]})
    for dy in (10, 30, 60):
        cdp.send(
            "Input.dispatchTouchEvent",
            {"type": "touchMove", "touchPoints": [{"x": cx + dy, "y": cy - dy}]},
        )
    state = lupin.wait_for(
        "a touch to drive the wheels",
        lambda s: s["mux"]["active"] == "manual" and any(wheel_goals(s)),
    )
    twist = state["base"]["twist"]
    assert twist["linear_x"] > 0 and twist["angular_z"] < 0  # forward, turning right
    cdp.send("Input.dispatchTouchEvent", {"type": "touchEnd", "touchPoints": []})
    lupin.wait_for("the wheels to stop", lambda s: not any(wheel_goals(s)), timeout=1.0)
    cdp.detach()


# -- E-stop ---------------------------------------------------------------------------


def test_estop_engages_releases_and_shows_the_daemons_state(open_hmi: Any, lupin: Lupin) -> None:
    page = open_hmi(LAPTOP)
    assert page.is_disabled("[data-testid=estop-release]")

    page.click("[data-testid=estop]")
    lupin.wait_for("the E-stop", lambda s: s["estop"])
    page.wait_for_selector("body.estop-on")
    assert text(page, "estop-label") == "E-STOP ENGAGED"
    assert text(page, "mux-lock") != "none"
    assert page.get_attribute("[data-testid=drive-pad]", "aria-disabled") == "true"
    screenshot(page, "hmi-laptop-estop")

    page.click("[data-testid=estop-release]")
    lupin.wait_for("the E-stop release", lambda s: not s["estop"])
    page.wait_for_selector("body:not(.estop-on)")
    assert page.is_disabled("[data-testid=estop-release]")

    # Engaged by someone else (curl, another tablet): the page shows it, no click needed.
    lupin.post("/api/estop", {"engaged": True})
    page.wait_for_selector("body.estop-on", timeout=2000)
    lupin.post("/api/estop", {"engaged": False})
    page.wait_for_selector("body:not(.estop-on)", timeout=2000)
    no_toast(page)


def test_estop_look_follows_the_daemon_and_survives_a_deaf_socket(
    browser: Any, lupin: Lupin
) -> None:
    context = browser.new_context(viewport=LAPTOP)
    try:

        def deaf_to_estop(ws: Any) -> None:
            server = ws.connect_to_server()
            ws.on_message(lambda msg: None if '"estop"' in str(msg) else server.send(msg))

        context.route_web_socket("**/api/ws", deaf_to_estop)
        context.route("**/api/estop", lambda route: route.abort())
        page = context.new_page()
        page.goto(lupin.url + "/")
        connected(page)
        # Neither path reaches the daemon: the page must not claim the E-stop is on.
        page.click("[data-testid=estop]")
        time.sleep(0.6)
        assert not lupin.state()["estop"]
        assert page.evaluate("document.body.classList.contains('estop-on')") is False
        assert text(page, "estop-label") == "E-STOP"
        # The socket still swallows it, but the E-stop also goes out over HTTP.
        context.unroute("**/api/estop")
        page.click("[data-testid=estop]")
        lupin.wait_for("the E-stop over HTTP", lambda s: s["estop"], timeout=2.0)
        page.wait_for_selector("body.estop-on", timeout=2000)
        # Escape engages too (released first by someone else).
        lupin.post("/api/estop", {"engaged": False})
        page.wait_for_selector("body:not(.estop-on)", timeout=2000)
        page.keyboard.press("Escape")
        lupin.wait_for("the E-stop from Escape", lambda s: s["estop"], timeout=2.0)
    finally:
        context.close()


# -- arm -------------------------------------------------------------------------------


def test_sliders_are_armed_not_live_seeded_and_report_closed_loop_status(
    open_hmi: Any, lupin: Lupin
) -> None:
    page = open_hmi(LAPTOP)
    joint = "shoulder_pan"  # no gravity on it in the sim: it settles exactly
    slider = f"[data-testid=slider-{joint}]"
    # Torque is off at boot (LUPIN_AUTO_HOME=false): every slider is locked.
    assert text(page, "torque-text") == "off"
    assert page.is_disabled(slider)
    assert "torque off" in text(page, "arm-gate")
    assert page.is_disabled("[data-testid=preset-home]")

    enable_torque(page, lupin)
    page.wait_for_selector(f"{slider}:not([disabled])")
    # Seeded from measured state: the thumb is where the joint is, not a phantom 0.
    measured = lupin.joint(joint)["position_deg"]
    assert abs(float(page.input_value(slider)) - measured) <= 1.0
    robot = lupin.get("/api/robot")
    window = next(j["window_deg"] for j in robot["joints"] if j["name"] == joint)
    assert [page.get_attribute(slider, "min"), page.get_attribute(slider, "max")] == [
        str(window[0]),
        str(window[1]),
    ]

    # Dragging sends nothing; the release sends one joint command at the rate slider's speed.
    page.eval_on_selector(
        "[data-testid=rate]",
        "el => { el.value = '20'; el.dispatchEvent(new Event('input', {bubbles: true})); }",
    )
    page.eval_on_selector(
        slider,
        "el => { el.dispatchEvent(new PointerEvent('pointerdown', {bubbles: true}));"
        " el.value = '-10'; el.dispatchEvent(new Event('input', {bubbles: true})); }",
    )
    time.sleep(0.3)
    assert sent(page, "joint") == []
    set_slider(page, f"slider-{joint}", -25)
    badge = f"document.querySelector('[data-testid=badge-{joint}]').textContent"
    page.wait_for_function(f"{badge} === 'moving'", timeout=3000)
    page.wait_for_function(f"{badge} === 'settled'", timeout=10000)
    joints = sent(page, "joint")
    assert [j["frame"]["angle_deg"] for j in joints] == [-25]
    assert joints[0]["frame"]["speed_deg_s"] == 20
    state = lupin.joint(joint)
    assert state["status"] == "settled"
    assert abs(state["target_deg"] - (-25)) < 0.5 and abs(state["position_deg"] - (-25)) < 2.0
    # The thumb now shows the daemon's target, not a guess.
    assert float(page.input_value(slider)) == -25
    no_toast(page)


def test_preset_init_and_gripper(open_hmi: Any, lupin: Lupin) -> None:
    page = open_hmi(LAPTOP)
    enable_torque(page, lupin)
    preset = lupin.get("/api/robot")["presets"]["pick"]
    page.click("[data-testid=preset-pick]")
    lupin.wait_for(
        "the pick preset's targets",
        lambda s: all(
            abs(j["target_deg"] - preset[j["name"]]) < 0.5
            for j in s["joints"]
            if j["name"] in preset
        ),
        timeout=2.0,
    )
    page.wait_for_function(
        "document.querySelector('[data-testid=badge-elbow_flex]').textContent === 'moving'"
    )
    lupin.wait_for(
        "the preset to finish",
        lambda s: all(
            j["status"] in ("settled", "stalled") for j in s["joints"] if j["name"] in preset
        ),
        timeout=8.0,
    )
    page.wait_for_function(
        "document.querySelector('[data-testid=badge-elbow_flex]').textContent === 'settled'"
    )
    # A joint that does not converge is shown stalled with the daemon's diagnosis.
    time.sleep(0.2)
    state = lupin.state()
    for js in state["joints"]:
        if js["status"] == "stalled":
            diagnosis = [e["diagnosis"] for e in state["events"] if e["joint"] == js["name"]][-1]
            row = f"[data-joint={js['name']}]"
            assert page.text_content(f"{row} .badge") == "stalled"
            assert page.text_content(f"{row} .diag") == diagnosis
    # Untouched sliders tracked the arm all the way there.
    elbow = float(page.input_value("[data-testid=slider-elbow_flex]"))
    assert abs(elbow - preset["elbow_flex"]) <= 1.5

    gripper = lupin.get("/api/robot")["gripper"]
    before = lupin.joint(gripper["joint"])["target_deg"]
    page.click("[data-testid=gripper-open]")
    lupin.wait_for(
        "the gripper to get a new target",
        lambda s: (
            next(j for j in s["joints"] if j["name"] == gripper["joint"])["target_deg"] != before
        ),
        timeout=2.0,
    )
    assert sent(page, "gripper")[0]["frame"]["angle_deg"] == gripper["hmi_open_deg"]

    page.click("[data-testid=init]")
    lupin.wait_for(
        "init's zero targets",
        lambda s: all(abs(j["target_deg"]) < 0.5 for j in s["joints"] if j["name"] in preset),
        timeout=2.0,
    )
    no_toast(page)


def test_refused_command_shows_the_daemons_message(open_hmi: Any, lupin: Lupin) -> None:
    # A taught pose too far away: only the daemon can know, and it says why.
    request = urllib.request.Request(
        lupin.url + "/api/arm/poses/far",
        data=json.dumps({"joints_rad": {"shoulder_lift": -1.2}}).encode(),
        headers={"Content-Type": "application/json"},
        method="PUT",
    )
    urllib.request.urlopen(request, timeout=5).close()
    page = open_hmi(LAPTOP)
    enable_torque(page, lupin)
    go = "#poses li[data-pose=far] .pose-go"
    page.wait_for_selector(f"{go}:not([disabled])")
    page.click(go)
    toast = page.wait_for_selector(".toast[data-tone='bad']", timeout=3000)
    assert "pose far" in toast.text_content()
    assert "max_travel" in toast.text_content()
    assert lupin.joint("shoulder_lift")["status"] != "moving"


# -- connection ----------------------------------------------------------------------------


def test_disconnected_page_disables_everything_and_shows_torque_unknown(
    browser: Any, lupin: Lupin
) -> None:
    lupin.post("/api/arm/torque", {"enabled": True})
    lupin.wait_for("torque on", lambda s: s["torque"] == "on")
    context = browser.new_context(viewport=PHONE, device_scale_factor=2)
    try:
        context.route_web_socket("**/api/ws", lambda ws: ws.close())
        page = context.new_page()
        page.goto(lupin.url + "/")
        page.wait_for_selector("#banner:not([hidden])")
        page.wait_for_function("document.getElementById('conn-text').textContent === 'offline'")
        # The daemon has torque on, but a page that has not heard so says unknown.
        assert text(page, "torque-text") == "unknown"
        for testid in ("torque-on", "torque-off", "init", "estop-release", "heal"):
            assert page.is_disabled(f"[data-testid={testid}]"), testid
        assert page.get_attribute("[data-testid=drive-pad]", "aria-disabled") == "true"
        assert page.locator("input[type=range]:not([disabled])").count() == 0
        assert page.is_enabled("[data-testid=estop]"), "the E-stop is never disabled"
        screenshot(page, "hmi-phone-offline")
    finally:
        context.close()


def test_reconnects_after_a_daemon_restart(open_hmi: Any, lupin: Lupin) -> None:
    page = open_hmi(LAPTOP)
    enable_torque(page, lupin)
    page.wait_for_selector("[data-testid=slider-elbow_flex]:not([disabled])")
    lupin.stop()
    page.wait_for_function("document.getElementById('conn-text').textContent === 'offline'")
    assert text(page, "torque-text") == "unknown"
    assert page.locator("input[type=range]:not([disabled])").count() == 0
    assert page.locator("#presets button:not([disabled])").count() == 0
    lupin.start_again()  # boots limp
    page.wait_for_function(
        "document.getElementById('conn-text').textContent === 'connected'", timeout=15000
    )
    page.wait_for_function("document.getElementById('torque-text').textContent === 'off'")
    assert page.is_disabled("[data-testid=slider-elbow_flex]")


# -- taught poses -----------------------------------------------------------------------


def test_taught_poses_save_go_delete(open_hmi: Any, lupin: Lupin) -> None:
    page = open_hmi(LAPTOP)
    page.fill("#pose-name", "bench_a")
    page.click("#pose-save")
    page.wait_for_selector("#poses li[data-pose=bench_a]")
    assert [p["name"] for p in lupin.get("/api/arm/poses")["poses"]] == ["bench_a"]

    go = "#poses li[data-pose=bench_a] .pose-go"
    assert page.is_disabled(go)  # armed, not live: torque is off
    enable_torque(page, lupin)
    page.wait_for_selector(f"{go}:not([disabled])")
    page.click(go)
    page.wait_for_function("window.__sent.some(s => s.frame.type === 'pose_go')")
    time.sleep(0.3)
    no_toast(page)

    delete = "#poses li[data-pose=bench_a] .pose-del"
    page.click(delete)
    assert lupin.get("/api/arm/poses")["poses"]  # one tap only asks
    page.click(delete)
    page.wait_for_selector("#poses li[data-pose=bench_a]", state="detached")
    assert lupin.get("/api/arm/poses")["poses"] == []


# -- screenshots --------------------------------------------------------------------------


def test_screenshots_phone_and_laptop(open_hmi: Any, lupin: Lupin) -> None:
    laptop = open_hmi(LAPTOP)
    enable_torque(laptop, lupin)
    laptop.select_option("#plot-joint", "elbow_flex")
    laptop.click("[data-testid=preset-inspect]")
    time.sleep(1.6)  # mid-move: badges moving, the trace drawing
    screenshot(laptop, "hmi-laptop")
    phone = open_hmi(PHONE, device_scale_factor=2, has_touch=True, is_mobile=True)
    time.sleep(2.0)
    screenshot(phone, "hmi-phone")
    no_toast(laptop)
    no_toast(phone)


# -- token ----------------------------------------------------------------------------------


def test_token_from_the_address_or_the_prompt(browser: Any, tmp_path: Path) -> None:
    home = tmp_path / "home"
    home.mkdir()
    daemon = start_lupin(home, tmp_path / "lupin.log", token="s3cret-token")
    context = browser.new_context(viewport=LAPTOP)
    try:
        page = context.new_page()
        # Given in the address once: used for the socket and for HTTP writes, then scrubbed.
        page.goto(daemon.url + "/#token=s3cret-token")
        connected(page)
        assert "token" not in page.url
        page.fill("#pose-name", "with_token")
        page.click("#pose-save")
        page.wait_for_selector("#poses li[data-pose=with_token]")

        # A wrong remembered token: the page asks for the right one instead of retrying forever.
        page.evaluate("localStorage.setItem('lupin.token', 'wrong')")
        page.reload()
        page.wait_for_selector("#banner .token-form", timeout=8000)
        assert text(page, "conn-text") == "token needed"
        page.fill("#banner .token-form input", "s3cret-token")
        page.click("#banner .token-form button")
        connected(page)
    finally:
        context.close()
        stop_lupin(daemon.proc)


def test_gripper_slider_is_seeded_from_the_measured_jaw_on_the_open_close_scale(
    browser: Any, lupin: Lupin
) -> None:
    """The daemon publishes the jaw's joint angles at its open and closed ends, so the
    slider is shown on the HMI's open/close scale and seeded from the measured jaw."""
    context = browser.new_context(viewport=LAPTOP)
    try:
        page = context.new_page()
        page.goto(lupin.url + "/")
        connected(page)
        slider = "[data-testid=gripper-slider]"
        assert page.is_visible(slider)
        info = lupin.get("/api/robot")["gripper"]
        open_rad, closed_rad = info["open_rad"], info["closed_rad"]
        jaw = lupin.joint(info["joint"])["position_deg"]
        f = (math.radians(jaw) - open_rad) / (closed_rad - open_rad)
        expected = info["hmi_open_deg"] + f * (info["hmi_closed_deg"] - info["hmi_open_deg"])
        assert abs(float(page.input_value(slider)) - expected) <= 1.0
        left = page.text_content("#gripper-left") or ""
        assert left.startswith(
            "open" if info["hmi_open_deg"] < info["hmi_closed_deg"] else "closed"
        )
        assert page.is_disabled(slider)  # armed, not live
        enable_torque(page, lupin)
        page.wait_for_selector(f"{slider}:not([disabled])")
        set_slider(page, "gripper-slider", 0)  # half way between the ends
        half = math.degrees((open_rad + closed_rad) / 2)
        lupin.wait_for(
            "the gripper's new target",
            lambda s: abs(lupin_joint(s, info["joint"])["target_deg"] - half) < 1.0,
            timeout=2.0,
        )
    finally:
        context.close()
