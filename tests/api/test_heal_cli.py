"""``lupin heal`` as a client of a running daemon, and ``lupin run`` serving the API."""

from __future__ import annotations

import asyncio
import re
import signal
from pathlib import Path

import aiohttp

from lupin.api import ApiServer
from lupintest.harness import child_env, lupin_cmd

from .conftest import TOKEN
from .helpers import free_port, lupin


async def test_heal_against_the_running_daemon(api: ApiServer, lupin_home: Path) -> None:
    code, out, err = await lupin(lupin_home, "heal", "--url", api.url)
    assert code == 0, err
    assert out.splitlines()[0] in ("heal: healthy", "heal: healed")
    assert "auto-home: disabled" in out


async def test_heal_with_a_token(api_token: ApiServer, lupin_home: Path) -> None:
    code, out, err = await lupin(lupin_home, "heal", "--url", api_token.url)
    assert code == 77 and "LUPIN_TOKEN" in err and "unauthorized" in err
    code, out, err = await lupin(lupin_home, "heal", "--url", api_token.url, token=TOKEN)
    assert code == 0 and out.startswith("heal: "), err
    code, out, err = await lupin(lupin_home, "heal", "--url", api_token.url, "--token", "nope")
    assert code == 77 and "wrong token" in err
    assert TOKEN not in out + err


async def test_heal_without_a_daemon_says_so(lupin_home: Path) -> None:
    url = f"http://127.0.0.1:{free_port()}"
    code, _out, err = await lupin(lupin_home, "heal", "--url", url)
    assert code == 69
    assert f"no Lupin daemon answering at {url}" in err and "lupin run" in err
    assert "Traceback" not in err


async def test_run_serves_the_api_on_the_real_port(lupin_home: Path) -> None:
    env = child_env(lupin_home)
    env["LUPIN_TOKEN"] = TOKEN
    env["LUPIN_AUTO_HOME"] = "false"
    proc = await asyncio.create_subprocess_exec(
        *lupin_cmd("run", "--sim", "--port", "0"),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env=env,
    )
    assert proc.stderr is not None
    log: list[str] = []
    try:
        async with asyncio.timeout(15):
            while not any("ready:" in line for line in log):
                line = (await proc.stderr.readline()).decode()
                assert line, "lupin run ended early:\n" + "".join(log)
                log.append(line)
        found = re.search(
            r"API listening on (http://127\.0\.0\.1:(\d+)) \(token required\)", "".join(log)
        )
        assert found, "".join(log)
        url, port = found.group(1), int(found.group(2))
        assert port != 0
        async with aiohttp.ClientSession() as http, http.get(url + "/api/health") as resp:
            assert resp.status == 200 and (await resp.json())["ok"] is True
        code, _out, err = await lupin(lupin_home, "heal", "--url", url, token=TOKEN)
        assert code == 0, err
        proc.send_signal(signal.SIGTERM)
        async with asyncio.timeout(5):
            rest = (await proc.stderr.read()).decode()
            assert await proc.wait() == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert TOKEN not in "".join(log) + rest
