"""Every example system passes `embagents check`; the chat-memory example keeps its conversation;
the vision example finds the astronaut's face and cuts two motion clips; the manager examples run their
missions to the end, the pick-and-place one through a SIGKILL of its manager mid-mission; the arm example
reaches its target. Each runs with only what the extras its docstring names (as the README does) install:
the other extras' modules are hidden from its processes."""

from __future__ import annotations

import ast
import json
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import (
    alsa_file_devices,
    hide_modules,
    modules_outside_extras,
    skip_unless_portaudio,
    wait_until,
)

EXAMPLES = Path(__file__).parents[1] / "examples"
README = Path(__file__).parents[1] / "README.md"
_INSTALL = r'pip install -e (?:"\.\[([\w,]+)\]"|\.(?![\w\[]))'


def documented_extras(name: str) -> list[str]:
    """The extras the example's docstring names: `pip install -e ".[a,b]"`, or `pip install -e .` for none."""
    doc = ast.get_docstring(ast.parse((EXAMPLES / name).read_text())) or ""
    m = re.search(_INSTALL, doc)
    assert m, f"examples/{name}: its docstring names no install line (pip install -e \".[EXTRAS]\" or pip install -e .)"
    return m[1].split(",") if m[1] else []


def as_installed(name: str, folder: Path, env: dict[str, str] | None = None,
                 extras: list[str] | None = None) -> dict[str, str]:
    """``env`` (default os.environ) in which the example's processes import only what its documented extras
    (or ``extras``) and the base dependencies install: every other extra's modules are hidden."""
    hidden = modules_outside_extras(documented_extras(name) if extras is None else extras)
    return hide_modules(folder / "as_installed", hidden, env)


def test_each_example_names_its_extras_and_the_readme_names_the_same() -> None:
    for example in sorted(EXAMPLES.glob("*.py")):
        documented_extras(example.name)  # each names its install line, or fails naming the example
    readme = README.read_text()
    said = re.findall(r'`(?:examples/)?(\w+\.py)`[^`]*?`' + _INSTALL, readme)
    said += [(n, x) for x, n in re.findall(_INSTALL + r' && embagents supervise examples/(\w+\.py)', readme)]
    assert {n for n, _ in said} >= {"chat.py", "listen.py", "voice.py", "vision.py", "arm.py", "memory.py",
                                    "ros_chat.py"}, said
    for name, extras in said:
        assert sorted(extras.split(",") if extras else []) == sorted(documented_extras(name)), (
            f"the README installs {extras!r} for examples/{name}; its docstring: {documented_extras(name)}")


@pytest.mark.parametrize("name", ["chat.py", "chat_memory.py", "ros_chat.py", "vision.py", "listen.py", "voice.py",
                                  "manager_pick_place.py", "manager_modes.py", "arm.py", "memory.py",
                                  "gpu_pipeline.py", "ros_goto.py"])
def test_example_systems_check_clean(name: str, tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "check", str(EXAMPLES / name)],
                         capture_output=True, text=True, timeout=120, env=as_installed(name, tmp_path))
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.startswith("OK:")


def test_chat_memory_survives_a_sigkill_of_the_llm(tmp_path: Path) -> None:
    pytest.importorskip("llama_cpp", reason="the example runs SmolLM2 (pip install 'embagents[llm]')")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "chat_memory.py")],
                         capture_output=True, text=True, timeout=300, env=as_installed("chat_memory.py", tmp_path))
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    lines = out.stdout.splitlines()
    assert lines[0] == "Q: My favourite colour is blue." and lines[1], out.stdout
    killed = re.fullmatch(r"\[demo\] SIGKILLed the llm \(pid (\d+)\); its supervisor starts a new one", lines[2])
    restored = re.fullmatch(r"\[demo\] the new llm \(pid (\d+)\) restored 2 messages of history", lines[3])
    assert killed and restored and killed[1] != restored[1], out.stdout
    assert lines[4] == "Q: What is my favourite colour?" and lines[5], out.stdout
    # The supervisor saw exactly the one SIGKILL the demo sent, and restarted that llm.
    crashes = [x for x in out.stderr.splitlines() if "crashed root/llm" in x]
    assert len(crashes) == 1 and f"pid={killed[1]}" in crashes[0] and "reason=killed" in crashes[0], out.stderr
    # A fresh start says so; only the restart restored a lifecycle state. Each starts configured and is
    # activated by the root once the other, which reads what it publishes, is up (ready before publishing).
    said = [x.split("supervisor.lifecycle: ")[1] for x in out.stderr.splitlines() if "supervisor.lifecycle: " in x]
    assert said == ["[llm] configured", "[demo] configured", "[llm] lifecycle restored to active"], out.stderr
    assert "activated llm: demo subscribed to text_out" in out.stderr, out.stderr
    assert "activated demo: llm subscribed to text_in" in out.stderr, out.stderr


def test_vision_example_finds_the_face_and_writes_the_image_and_clips(tmp_path: Path) -> None:
    for module in ("onnxruntime", "cv2", "skimage", "supervision"):
        pytest.importorskip(module, reason="the example needs the vision extra (pip install 'embagents[vision]')")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "vision.py")],
                         capture_output=True, text=True, timeout=180,
                         env=as_installed("vision.py", tmp_path, {**os.environ, "EMBAGENTS_VISION_OUT": str(tmp_path)}))
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    found = [re.fullmatch(r"detection: face (0\.9\d\d|1\.000) box \((\d+), (\d+), (\d+), (\d+)\)", x)
             for x in out.stdout.splitlines() if x.startswith("detection:")]
    assert len(found) >= 10 and all(found), out.stdout
    x1, y1, x2, y2 = (int(v) for v in found[0].groups()[1:])  # the first frame: her face, top middle
    assert 150 < x1 < 200 and 20 < y1 < 60 and 240 < x2 < 290 and 130 < y2 < 180, out.stdout
    assert (tmp_path / "annotated.png").stat().st_size > 10_000
    clips = sorted(tmp_path.glob("motion_clip_*.mp4"))
    assert [c.name for c in clips] == ["motion_clip_1.mp4", "motion_clip_2.mp4"], out.stdout
    assert out.stdout.splitlines()[-1] == f"done: 2 clips in {tmp_path}", out.stdout


def test_listen_example_hears_the_six_phrases_of_the_clip(tmp_path: Path) -> None:
    pytest.importorskip("sherpa_onnx", reason="the example needs the speech extra (pip install 'embagents[speech]')")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "listen.py")],
                         capture_output=True, text=True, timeout=180, env=as_installed("listen.py", tmp_path))
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    heard = [re.sub(r"[^a-z ]", "", x[len("heard: "):].lower()) for x in out.stdout.splitlines() if x.startswith("heard: ")]
    assert heard == ["ever tried", "ever failed", "no matter", "try again", "fail again", "fail better"], out.stdout
    assert any(x.startswith("  (hearing: ") for x in out.stdout.splitlines()), out.stdout  # partial transcripts
    assert out.stdout.splitlines()[-1] == "done: 6 phrases heard", out.stdout


def test_voice_example_is_interrupted_mid_answer_once_and_speaks_on_over_a_backchannel(tmp_path: Path) -> None:
    # The user's part is scripted against the simulated speaker (examples/voice.py's USER_TURNS): "Tell me about
    # Paris."; 1 s into the answer, "Wait, tell me about Berlin instead."; 2 s into that answer, "Uh-huh."
    for module in ("sherpa_onnx", "espeakng_loader", "livekit", "llama_cpp"):
        pytest.importorskip(module, reason="the example needs the llm and speech extras (pip install 'embagents[llm,speech]')")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "voice.py")],
                         capture_output=True, text=True, timeout=240,
                         env=as_installed("voice.py", tmp_path, {**os.environ, "EMBAGENTS_VOICE_OUT": str(tmp_path)}))
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    lines = out.stdout.splitlines()
    heard = [x[len("heard: "):] for x in lines if x.startswith("heard: ")]
    said = [x[len("said: "):] for x in lines if x.startswith("said: ")]
    assert heard[0] == "Tell me about Paris." and "berlin" in heard[1].lower() and len(heard) == 2, out.stdout
    assert len(said) == 2, out.stdout
    # One interruption: the robot stopped 1 s into its first answer, cut short after the words it had said.
    cut = [re.fullmatch(r'barge-in: user interrupted answer (\d) after (\d+\.\d) s \(cut short at "(.*)"\)', x)
           for x in lines if x.startswith("barge-in: ")]
    assert len(cut) == 1 and cut[0] and cut[0][1] == "1" and 0.8 <= float(cut[0][2]) <= 2.5, out.stdout
    words_said = " ".join(said[0].split())
    assert cut[0][3] and words_said.find(cut[0][3].removeprefix("...")) in (0, len(cut[0][3]) - 70), out.stdout
    assert len(cut[0][3].removeprefix("...")) < len(words_said), out.stdout
    # One backchannel: the robot paused while the user spoke, then went on and played its answer to the end.
    from embagents.components.speech_to_text import is_backchannel

    # What Whisper heard of it: a backchannel, or one word ("Oh.", "Wow."), as a short sound takes two
    # (interrupt_min_words) to interrupt; or no words ("noise ignored", as the robot's own echo at the start of
    # an answer is, now and then).
    nods = [re.fullmatch(r'(?:backchannel ignored: "(.+)"|noise ignored) during answer (\d) \(the robot paused '
                         r'(\d+\.\d) s, then went on\)', x) for x in lines if x.startswith(("backchannel ", "noise "))]
    assert all(nods) and [m[2] for m in nods if m].count("2") == 1, out.stdout
    nod = next(m for m in nods if m and m[2] == "2")
    assert nod[1] is None or is_backchannel(nod[1]) or len(re.findall(r"[\w']+", nod[1])) == 1, out.stdout
    # The LLM keeps the answer cut short as the words played (the speaker's), not all it had written.
    import ast

    kept = [ast.literal_eval(x[len("history: "):]) for x in lines if x.startswith("history: ")]
    assert len(kept) == 1 and kept[0]["role"] == "assistant" and kept[0]["interrupted"] is True, out.stdout
    assert kept[0]["content"].endswith(cut[0][3].removeprefix("...")), out.stdout
    assert words_said.startswith(kept[0]["content"]) and len(kept[0]["content"]) < len(words_said), out.stdout
    said_nod = sum(m is not None and m[1] is not None for m in nods)
    done = re.fullmatch(rf"done: 1 interruption, {said_nod} backchannel ignored; answer 2 played (\d+\.\d) s of "
                        r"(\d+\.\d) s", lines[-1])
    assert done and float(done[1]) == float(done[2]) > 2.0, out.stdout
    # Each turn's latency per stage, the speaker's start included (the second too: after a stop, a new utterance).
    stages = [dict(x.rsplit(" ", 2)[:2] for x in line[len("stages: "):].split(", "))
              for line in lines if line.startswith("stages: ")]
    assert [list(s) for s in stages] == [["eou_delay", "transcription_delay", "ttft", "ttfb", "playout_delay",
                                          "total"]] * 2, out.stdout
    assert [x for x in lines if x.startswith("answer audio: ")] == [
        f"answer audio: {tmp_path / 'answer-1.wav'}", f"answer audio: {tmp_path / 'answer-2.wav'}"], out.stdout
    # The second answer's audio, heard by the real recognizer, says what the LLM wrote.
    from embagents.components import read_wav
    from embagents.components.audio_format import to_mono_16k
    from embagents.models.backends.sherpa_stt import SherpaRecognizer
    from embagents.models.files.speech import whisper_tiny_en_dir
    from embagents.msgs import Audio

    samples, rate, channels = read_wav(str(tmp_path / "answer-2.wav"))
    words = SherpaRecognizer(whisper_tiny_en_dir(progress=False)).transcribe(
        to_mono_16k(Audio(data=samples, sample_rate=rate, channels=channels))[0])
    first = re.findall(r"[a-z']+", said[1].lower())[:6]
    assert len(set(first) & set(re.findall(r"[a-z']+", words.lower()))) >= 3, (said[1], words)


def test_voice_example_listens_live_on_a_microphone_and_answers_through_a_speaker(tmp_path: Path) -> None:
    # A microphone and a speaker with no sound card: ALSA's file plugin (tests/helpers.alsa_file_devices).
    pytest.importorskip("sherpa_onnx", reason="the example needs the speech extra (pip install 'embagents[speech]')")
    skip_unless_portaudio()
    from embagents.components import read_wav
    from embagents.components.audio_io import spoken_clip_path

    question, rate, _ = read_wav(spoken_clip_path("What is the capital of France?", progress=False))
    assert rate == 16000
    np.concatenate([question, np.zeros(3 * rate, np.int16)]).astype("<i2").tofile(tmp_path / "mic.raw")
    env = {**os.environ, "EMBAGENTS_KEEP_RUNNING": "1", "EMBAGENTS_MIC_DEVICE": "robotmic",
           "EMBAGENTS_SPEAKER_DEVICE": "robotspeaker", "ALSA_CONFIG_PATH": alsa_file_devices(tmp_path),
           "EMBAGENTS_VOICE_OUT": str(tmp_path)}
    proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "voice.py")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=as_installed("voice.py", tmp_path, env))
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # it keeps listening: read until the answer has been spoken
            lines.append(line.rstrip("\n"))
            if line.startswith("answer audio: "):
                break
        played = tmp_path / "speaker.raw"
        wait_until(lambda: played.is_file() and played.stat().st_size > 16000, 30, "the speaker to play the answer")
    finally:
        proc.send_signal(signal.SIGINT)  # Ctrl-C: a clean stop
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, "\n".join(lines) + err[-3000:]
    assert "voice: listening live on robotmic; Ctrl-C or `embagents stop` stops it" in lines, lines
    assert "heard: What is the capital of France?" in lines, lines
    assert any(x.startswith("said: ") and "Paris" in x for x in lines), lines


def test_pick_place_resumes_its_state_machine_after_a_sigkill_of_the_manager(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "manager_pick_place.py")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=as_installed("manager_pick_place.py", tmp_path))
    err: list[str] = []
    killed = threading.Event()

    def read_stderr() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            err.append(line)
            pid = re.search(r"embagents.manager.pick_place: pid (\d+):", line)
            if pid:
                manager = int(pid[1])
            if not killed.is_set() and "PickPlace: grasp -> carry" in line:
                # Mid-mission, carrying the first cube (it takes over a second), after the tick that entered
                # 'carry' has ended and been snapshotted: a kill inside a tick resumes from the tick before.
                killed.set()
                threading.Timer(0.3, os.kill, (manager, signal.SIGKILL)).start()

    reader = threading.Thread(target=read_stderr)
    reader.start()
    timer = threading.Timer(90, proc.kill)  # a safety net: the mission takes about ten seconds
    timer.start()
    try:
        assert proc.stdout is not None
        out = proc.stdout.read()  # this thread reads stdout only: the reader above owns stderr
        proc.wait()
    finally:
        timer.cancel()
        proc.kill()
        reader.join()
    log = "".join(err)
    assert proc.returncode == 0 and killed.is_set(), out + log[-3000:]
    assert "restarted: resuming at tick" in log and "handler 'PickPlace' in state 'carry'" in log, log[-3000:]
    assert out.splitlines()[-1] == "done: the table is clear (3 cubes in the bin)", out
    placed = [x for x in out.splitlines() if x.startswith("placed the")]
    assert len(placed) == 3, out  # each cube once: the restart neither lost nor repeated a step


def test_modes_example_goes_through_its_modes_to_the_goal(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "manager_modes.py")],
                         capture_output=True, text=True, timeout=90, env=as_installed("manager_modes.py", tmp_path))
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    modes = re.findall(r"mode (\w+) -> (\w+)", out.stdout)
    assert modes == [("None", "cold_start"), ("cold_start", "turn"), ("turn", "navigation"),
                     ("navigation", "arrived")], out.stdout
    x, y = (float(v) for v in re.search(r"arrived at \((\S+), (\S+)\)", out.stdout).groups())  # type: ignore[union-attr]
    assert abs(x - 1.5) < 0.1 and abs(y - 1.0) < 0.1, out.stdout


def test_arm_example_reaches_its_target_and_exits_0(tmp_path: Path) -> None:
    for module in ("pybullet", "onnxruntime", "onnx", "urdf_parser_py", "cv2"):
        pytest.importorskip(module, reason="the example needs the sim extra (pip install 'embagents[sim]')")
    env = {**os.environ, "EMBAGENTS_ARM_OUT": str(tmp_path / "out"), "EMBAGENTS_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "arm.py")],
                         capture_output=True, text=True, timeout=180, env=as_installed("arm.py", tmp_path, env))
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    lines = out.stdout.splitlines()
    errors = [float(x.split()[2]) for x in lines if x.startswith("joint error:")]
    assert len(errors) >= 2 and errors[0] > 0.05 and errors[-1] <= 0.01, out.stdout  # it moved, then got there
    assert errors == sorted(errors, reverse=True), out.stdout  # closer every second
    assert lines[-1] == "done: reached the target" and any(x.startswith("describe: skipped: ") for x in lines)
    assert (tmp_path / "out" / "arm.png").stat().st_size > 1000
    assert "task 'reach the target pose' started" in out.stderr  # the event called manipulate in the VLA's process


def test_arm_example_reaches_its_target_with_its_policy_behind_openpis_websocket(tmp_path: Path) -> None:
    for module in ("pybullet", "onnxruntime", "onnx", "urdf_parser_py", "cv2", "websockets"):
        pytest.importorskip(module, reason="the example's openpi mode needs the sim and vla extras")
    from tests.helpers import free_port

    env = {**os.environ, "EMBAGENTS_ARM_OUT": str(tmp_path / "out"), "EMBAGENTS_CACHE_DIR": str(tmp_path / "cache"),
           "EMBAGENTS_POLICY": "openpi", "EMBAGENTS_POLICY_PORT": str(free_port())}
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "arm.py")],
                         capture_output=True, text=True, timeout=180,
                         env=as_installed("arm.py", tmp_path, env, extras=["sim", "vla"]))  # as its docstring says
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    assert out.stdout.splitlines()[-1] == "done: reached the target"
    assert "serving policy reach over openpi's protocol on ws://127.0.0.1:" in out.stderr
    assert "reach: connected to ws://127.0.0.1:" in out.stderr  # the VLA's OpenPIPolicyClient, not a local client


def test_arm_example_records_its_reach_as_a_lerobot_dataset_that_reads_back_frame_for_frame(tmp_path: Path) -> None:
    for module in ("pybullet", "onnxruntime", "onnx", "urdf_parser_py", "cv2", "pyarrow", "av"):
        pytest.importorskip(module, reason="the example's recording needs the sim and dataset extras")
    import av
    import cv2
    import pyarrow.parquet as pq

    root = tmp_path / "dataset"
    env = {**os.environ, "EMBAGENTS_ARM_OUT": str(tmp_path / "out"), "EMBAGENTS_CACHE_DIR": str(tmp_path / "cache"),
           "EMBAGENTS_ARM_DATASET": str(root)}
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "arm.py")],
                         capture_output=True, text=True, timeout=180,
                         env=as_installed("arm.py", tmp_path, env, extras=["sim", "dataset"]))  # as its docstring says
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["features"]["observation.state"]["names"] == [f"panda_joint{i}" for i in range(1, 8)]
    assert info["total_episodes"] == 1 and info["fps"] == 10.0 and info["robot_type"] == "franka_panda"
    (episode,) = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    assert episode["tasks"] == ["reach the target pose"] and episode["length"] > 10
    data = pq.read_table(root / "data" / "chunk-000" / "file-000.parquet").to_pydict()
    with av.open(str(root / "videos" / "observation.images.front" / "chunk-000" / "file-000.mp4")) as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(data["index"]) == len(frames) == episode["length"]  # one video frame per row
    state, action = np.array(data["observation.state"]), np.array(data["action"])
    assert state.shape == action.shape == (len(frames), 7)
    assert np.abs(state[-1] - [1.0, 0.4, -0.5, -1.4, 0.5, 2.3, 0.2]).max() < 0.05  # it reached the example's target
    saved = cv2.cvtColor(cv2.imread(str(tmp_path / "out" / "arm.png")), cv2.COLOR_BGR2RGB)
    assert frames[-1].shape == saved.shape and float(np.abs(frames[-1].astype(int) - saved.astype(int)).mean()) < 6


def test_arm_example_describes_its_camera_with_a_vlm_when_one_is_present(tmp_path: Path) -> None:
    for module in ("pybullet", "onnxruntime", "onnx", "urdf_parser_py", "llama_cpp", "gguf"):
        pytest.importorskip(module, reason="the example needs the sim and llm extras")
    from tests.embagents.fixtures.tiny_llama import make_tiny_llama_gguf
    from tests.embagents.fixtures.tiny_vlm import make_tiny_mmproj_gguf

    tiny_vlm = make_tiny_llama_gguf(str(tmp_path / "vlm" / "tiny-llava-text.gguf"))
    make_tiny_mmproj_gguf(str(tmp_path / "vlm" / "tiny-llava-mmproj.gguf"))  # found beside the language model
    env = {**os.environ, "EMBAGENTS_ARM_OUT": str(tmp_path / "out"), "EMBAGENTS_CACHE_DIR": str(tmp_path / "cache"),
           "EMBAGENTS_VLM_MODEL": tiny_vlm, "EMBAGENTS_VLM_HANDLER": "llava15"}  # the tiny LLaVA-style model
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "arm.py")],
                         capture_output=True, text=True, timeout=180,
                         env=as_installed("arm.py", tmp_path, env, extras=["sim", "llm"]))  # as its docstring says
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    lines = out.stdout.splitlines()
    described = [x for x in lines if x.startswith("describe: ")]
    assert described[0] == "describe: asking the VLM about the first camera frame", out.stdout
    assert len(described) == 2 and "skipped" not in described[1] and "no answer" not in described[1], (
        out.stdout + out.stderr[-3000:])
    assert lines[-1] == "done: reached the target"
    assert "event 'first_frame' fired" in out.stderr  # the event asked the VLM in the VLM's process


def test_memory_example_answers_where_the_cup_was_from_a_tool_call(tmp_path: Path) -> None:
    for module in ("llama_cpp", "onnxruntime", "apsw", "sqlite_vec", "tokenizers"):
        pytest.importorskip(module, reason="the example needs the llm and memory extras")
    out = subprocess.run([sys.executable, "-m", "embagents.cli", "supervise", str(EXAMPLES / "memory.py")],
                         capture_output=True, text=True, timeout=240,
                         env=as_installed("memory.py", tmp_path, {**os.environ, "EMBAGENTS_MEMORY_DB": str(tmp_path / "memory.db")}))
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    lines = out.stdout.splitlines()
    assert "[base] at (4.0, 2.0): sees cup, bottle; note: the kitchen table" in lines, out.stdout
    assert lines[-4] == "Q: Where did you see the cup?", out.stdout
    assert lines[-3] == 'tool call: locate({"what": "cup"})', out.stdout
    assert re.fullmatch(r"tool result: I last saw cup \d+ s ago at x=4\.0, y=2\.0, near the kitchen table", lines[-2])
    assert lines[-1].startswith("A: ") and "kitchen table" in lines[-1], out.stdout
    # The call crossed processes: the events actor ran it in memory's actor.
    assert "[_events] INFO embagents.events: tool call memory.locate(what='cup')" in out.stderr
