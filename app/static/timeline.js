// A playback bar for one Player: play/pause, a scrubber over the clip's time, and a
// frame/time readout. The search page and the clip page use it.
//
// Built to be extended: `track` is a positioned box around the scrubber where overlays
// (e.g. a selected span of time) can be placed, and `timeAt(clientX)` / `xAt(seconds)` map
// between a pointer position and the clip's time.

import { el, nextId } from "./util.js";

const READOUT_MS = 100;

/** Seconds with two decimals ("2.9999970000000005" -> "3.00 s"). */
export function formatTime(seconds) {
  return Number.isFinite(seconds) ? `${seconds.toFixed(2)} s` : "–";
}

export class Timeline {
  /**
   * player: the Player to drive; label: the group's accessible name.
   */
  constructor(player, { label = "Playback" } = {}) {
    this.player = player;
    this.duration = 0;
    this.fps = null;
    this.frameCount = 0;
    this.firstFrame = 0;
    const scrubId = nextId("time");
    this.playButton = el("button", { type: "button", class: "play", "aria-pressed": String(player.playing) }, player.playing ? "Pause" : "Play");
    this.scrub = el("input", { id: scrubId, type: "range", min: "0", max: "1", step: "0.01", value: "0" });
    this.readout = el("output", { for: scrubId, class: "clock", "aria-live": "off" }, "0.00 s");
    this.track = el("div", { class: "timeline-track" }, this.scrub);
    this.node = el(
      "div",
      { class: "player-controls timeline", role: "group", "aria-label": label },
      this.playButton,
      el("label", { for: scrubId }, "Time"),
      this.track,
      this.readout,
    );
    this.playButton.addEventListener("click", () => this.setPlaying(!this.player.playing));
    this.scrub.addEventListener("input", () => {
      const time = Number(this.scrub.value); // before update() moves the thumb back
      this.player.seek(time);
      this.setPlaying(false);
    });
    this.timer = setInterval(() => this.update(), READOUT_MS);
  }

  /**
   * The clip's length: `duration` seconds. With `fps` and `frameCount` the readout shows the
   * frame too, counted from `firstFrame` (e.g. the lead-in frames a preview leaves out).
   */
  setLength(duration, { fps = null, frameCount = 0, firstFrame = 0 } = {}) {
    this.duration = Math.max(0, duration || 0);
    this.fps = fps;
    this.frameCount = frameCount;
    this.firstFrame = firstFrame;
    this.player.loop = this.duration;
    this.scrub.max = String(this.duration || 1);
    this.scrub.step = "any";
    this.update();
  }

  setPlaying(playing) {
    this.player.setPlaying(playing);
    this.update();
  }

  /** Seconds at a pointer's x position over the track (clamped to the clip). */
  timeAt(clientX) {
    const box = this.scrub.getBoundingClientRect();
    const fraction = box.width > 0 ? (clientX - box.left) / box.width : 0;
    return Math.min(1, Math.max(0, fraction)) * this.duration;
  }

  /** The x offset (CSS pixels, within `track`) of a time. */
  xAt(seconds) {
    const box = this.scrub.getBoundingClientRect();
    return this.duration > 0 ? (seconds / this.duration) * box.width : 0;
  }

  update() {
    const time = this.player.time;
    this.scrub.value = String(time);
    const playing = this.player.playing;
    this.playButton.textContent = playing ? "Pause" : "Play";
    this.playButton.setAttribute("aria-pressed", String(playing));
    if (this.fps && this.frameCount) {
      const frame = Math.min(this.frameCount - 1, this.firstFrame + Math.floor(time * this.fps + 1e-6));
      this.readout.textContent = `frame ${frame + 1} / ${this.frameCount} · ${formatTime(time)} / ${formatTime(this.duration)}`;
      this.readout.dataset.frame = String(frame);
    } else {
      this.readout.textContent = formatTime(time);
    }
  }

  dispose() {
    clearInterval(this.timer);
  }
}
