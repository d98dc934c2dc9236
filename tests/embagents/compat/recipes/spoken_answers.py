"""Spoken answers: speech in, an LLM's answer out loud, with RoboML's Whisper and transformers TTS."""

from agents.clients import OllamaClient, RoboMLHTTPClient, RoboMLWSClient
from agents.components import LLM, SpeechToText, TextToSpeech
from agents.config import SpeechToTextConfig, TextToSpeechConfig
from agents.models import OllamaModel, TransformersTTS, Whisper
from agents.ros import Launcher, Topic

audio_in = Topic(name="audio0", msg_type="Audio")
heard = Topic(name="heard", msg_type="String")

ears = SpeechToText(
    inputs=[audio_in],
    outputs=[heard],
    model_client=RoboMLHTTPClient(Whisper(name="whisper")),
    trigger=audio_in,
    config=SpeechToTextConfig(enable_vad=True, min_silence_duration_ms=400),
    component_name="ears",
)

reply = Topic(name="reply", msg_type="String")
brain = LLM(
    inputs=[heard],
    outputs=[reply],
    model_client=OllamaClient(OllamaModel(name="llama", checkpoint="llama3.2:3b")),
    trigger=heard,
    component_name="brain",
)

voice = TextToSpeech(
    inputs=[reply],
    outputs=[Topic(name="audio_out", msg_type="Audio")],
    model_client=RoboMLWSClient(TransformersTTS(name="tts")),
    trigger=reply,
    config=TextToSpeechConfig(play_on_device=False),
    component_name="voice",
)

launcher = Launcher()
launcher.enable_ui(inputs=[audio_in], outputs=[reply])
launcher.add_pkg(components=[ears, brain, voice], package_name="spoken_answers")
launcher.bringup()
