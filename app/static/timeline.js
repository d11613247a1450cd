// A playback bar for one Player: play/pause, a time rail over the clip, and a frame/time
// readout. The search page and the clip page use it.
//
// The rail is drawn here (not a native range input, whose thumb travels over less than its
// width): time t is at x = (t - view start) / (view length) × the rail's width, exactly, for
// the thumb and for any overlay placed in `track` (the clip page's span band), which has the
// rail's box. With `zoomable`, the rail shows a part of the clip (`view`), zoomed in and out
// around the playhead, and a strip under it shows where that part lies in the whole take.
//
// Keys (bindKeys): Space plays or pauses, ←/→ step a frame, Shift+←/→ a second, Home/End go
// to the start/end, +/− zoom; the page may add its own (the clip page's [ and ]).

import { el, nextId } from "./util.js";

const READOUT_MS = 100;

/** Seconds with two decimals ("2.9999970000000005" -> "3.00 s"; 83.5 -> "1:23.50"). */
export function formatTime(value) {
  if (!Number.isFinite(value)) return "–";
  const seconds = Math.round(value * 100) / 100; // 59.99994 is 1:00.00, not 60.00 s
  if (seconds < 60) return `${seconds.toFixed(2)} s`;
  const hours = Math.floor(seconds / 3600);
  const minutes = Math.floor((seconds - hours * 3600) / 60);
  const rest = (seconds - hours * 3600 - minutes * 60).toFixed(2).padStart(5, "0");
  return hours ? `${hours}:${String(minutes).padStart(2, "0")}:${rest}` : `${minutes}:${rest}`;
}

/** Whether a key press belongs to a control that uses keys itself (typing, choosing). */
function typingIn(target) {
  if (!(target instanceof Element)) return false;
  if (target.closest("dialog[open]")) return true;
  return Boolean(target.closest("input, textarea, select, [contenteditable=''], [contenteditable='true']"));
}

export class Timeline {
  /**
   * player: the Player to drive; label: the group's accessible name; zoomable: the rail can
   * show a part of the clip (the clip page's long takes).
   */
  constructor(player, { label = "Playback", zoomable = false } = {}) {
    this.player = player;
    this.duration = 0;
    this.fps = null;
    this.frameCount = 0;
    this.firstFrame = 0;
    this.zoomable = zoomable;
    this.view = [0, 0];
    this.viewListeners = new Set();
    this.playButton = el("button", { type: "button", class: "play", "aria-pressed": String(player.playing) }, player.playing ? "Pause" : "Play");
    this.thumb = el("div", { class: "timeline-thumb" });
    this.played = el("div", { class: "timeline-played" });
    const readoutId = nextId("time");
    this.rail = el(
      "div",
      {
        class: "timeline-rail",
        role: "slider",
        tabindex: "0",
        "aria-label": "Time",
        "aria-valuemin": "0",
        "aria-valuemax": "0",
        "aria-valuenow": "0",
        "aria-describedby": readoutId,
      },
      el("div", { class: "timeline-bar" }),
      this.played,
      this.thumb,
    );
    this.track = el("div", { class: "timeline-track" }, this.rail);
    this.readout = el("output", { id: readoutId, class: "clock", "aria-live": "off" }, "0.00 s");
    this.viewFrom = el("span", { class: "timeline-from" });
    this.viewTo = el("span", { class: "timeline-to" });
    this.window = el("div", { class: "timeline-window" });
    this.overview = el(
      "div",
      { class: "timeline-overview", title: "The whole take; the box is the part shown above (drag it)", "aria-hidden": "true" },
      el("div", { class: "timeline-overview-head" }),
      this.window,
    );
    const zoomIn = el("button", { type: "button", class: "secondary zoom", "aria-label": "Zoom in", title: "Zoom in (+)" }, "+");
    const zoomOut = el("button", { type: "button", class: "secondary zoom", "aria-label": "Zoom out", title: "Zoom out (−)" }, "−");
    const whole = el("button", { type: "button", class: "secondary zoom-all", title: "Show the whole take" }, "Whole take");
    this.zoomButtons = { zoomIn, zoomOut, whole };
    this.node = el(
      "div",
      { class: `player-controls timeline${zoomable ? " zoomable" : ""}`, role: "group", "aria-label": label },
      this.playButton,
      el(
        "div",
        { class: "timeline-main" },
        this.track,
        zoomable ? el("div", { class: "timeline-scale" }, this.viewFrom, this.viewTo) : null,
        zoomable ? this.overview : null,
      ),
      zoomable ? el("div", { class: "zoom-buttons", role: "group", "aria-label": "Zoom" }, zoomOut, zoomIn, whole) : null,
      this.readout,
    );
    this.playButton.addEventListener("click", () => this.setPlaying(!this.player.playing));
    zoomIn.addEventListener("click", () => this.zoom(0.5));
    zoomOut.addEventListener("click", () => this.zoom(2));
    whole.addEventListener("click", () => this.setView(0, this.duration));

    // Pointer on the rail: seek there (and pause), following a drag.
    let scrubbing = false;
    this.rail.addEventListener("pointerdown", (event) => {
      if (!this.duration || event.button !== 0) return;
      scrubbing = true;
      this.rail.setPointerCapture(event.pointerId);
      this.scrubTo(this.timeAt(event.clientX));
      this.rail.focus({ preventScroll: true });
      event.preventDefault();
    });
    this.rail.addEventListener("pointermove", (event) => {
      if (scrubbing) this.scrubTo(this.timeAt(event.clientX));
    });
    const stop = () => {
      scrubbing = false;
    };
    this.rail.addEventListener("pointerup", stop);
    this.rail.addEventListener("pointercancel", stop);
    this.rail.addEventListener("wheel", (event) => {
      if (!this.zoomable || !(event.ctrlKey || event.metaKey)) return; // pinch, or Ctrl + wheel
      event.preventDefault();
      this.zoom(event.deltaY < 0 ? 0.8 : 1.25, this.timeAt(event.clientX));
    }, { passive: false });
    // The overview strip: press or drag to move the part shown.
    let panning = false;
    const panTo = (clientX) => {
      const box = this.overview.getBoundingClientRect();
      const centre = (Math.min(1, Math.max(0, (clientX - box.left) / Math.max(1, box.width)))) * this.duration;
      const length = this.view[1] - this.view[0];
      this.setView(centre - length / 2, centre + length / 2);
    };
    this.overview.addEventListener("pointerdown", (event) => {
      panning = true;
      this.overview.setPointerCapture(event.pointerId);
      panTo(event.clientX);
      event.preventDefault();
    });
    this.overview.addEventListener("pointermove", (event) => {
      if (panning) panTo(event.clientX);
    });
    this.overview.addEventListener("pointerup", () => {
      panning = false;
    });
    // Keys on the rail itself (the page may bind the same keys more widely: bindKeys).
    this.rail.addEventListener("keydown", (event) => {
      if (this.handleKey(event)) {
        event.preventDefault();
        event.stopPropagation();
      }
    });
    this.timer = setInterval(() => this.update(), READOUT_MS);
    this.resize = new ResizeObserver(() => this.notifyView());
    this.resize.observe(this.rail);
  }

  /**
   * The clip's length: `duration` seconds. With `fps` and `frameCount` the readout shows the
   * frame too, counted from `firstFrame` (e.g. the lead-in frames a preview leaves out), and
   * the arrow keys step those frames.
   */
  setLength(duration, { fps = null, frameCount = 0, firstFrame = 0 } = {}) {
    this.duration = Math.max(0, duration || 0);
    this.fps = fps;
    this.frameCount = frameCount;
    this.firstFrame = firstFrame;
    this.player.loop = this.duration;
    this.rail.setAttribute("aria-valuemax", this.duration.toFixed(2));
    this.setView(0, this.duration);
  }

  /** Show seconds [from, to) of the clip on the rail (kept within the clip). */
  setView(from, to) {
    const shortest = Math.min(this.duration, Math.max(1, 20 / (this.fps || 30)));
    let length = Math.min(this.duration, Math.max(shortest, to - from));
    let start = Math.min(Math.max(0, from), this.duration - length);
    if (!Number.isFinite(start)) start = 0;
    if (!Number.isFinite(length)) length = 0;
    this.view = [start, start + length];
    this.update();
    this.notifyView();
  }

  /** Zoom by `factor` (< 1: in) around `around` seconds (default: the playhead). */
  zoom(factor, around = this.player.time) {
    const [a, b] = this.view;
    const length = (b - a) * factor;
    const where = b > a ? (around - a) / (b - a) : 0.5;
    const at = Math.min(1, Math.max(0, where));
    this.setView(around - at * length, around - at * length + length);
  }

  get zoomed() {
    return this.view[1] - this.view[0] < this.duration - 1e-9;
  }

  /** listener() is called when the part shown or the rail's size changes. */
  onView(listener) {
    this.viewListeners.add(listener);
  }

  notifyView() {
    for (const listener of this.viewListeners) listener(this);
  }

  setPlaying(playing) {
    this.player.setPlaying(playing);
    this.update();
  }

  /** Go to `seconds`, paused (the user is looking for a moment). */
  scrubTo(seconds) {
    this.player.seek(Math.min(this.duration, Math.max(0, seconds)));
    this.setPlaying(false);
  }

  /** Step `frames` frames of the file (30 a second when its rate is not known), pausing. */
  step(frames) {
    const fps = this.fps || 30;
    const current = Math.floor(this.player.time * fps + 1e-6);
    const last = Math.max(0, Math.ceil(this.duration * fps - 1e-6) - 1);
    const next = Math.min(last, Math.max(0, current + frames));
    this.scrubTo(next / fps);
  }

  /** Seconds at a pointer's x position over the rail (clamped to the part shown). */
  timeAt(clientX) {
    const box = this.rail.getBoundingClientRect();
    const fraction = box.width > 0 ? (clientX - box.left) / box.width : 0;
    const [a, b] = this.view;
    return a + Math.min(1, Math.max(0, fraction)) * (b - a);
  }

  /** The x offset (CSS pixels, within `track`) of a time (outside [0, width] when the time
   * is outside the part shown). */
  xAt(seconds) {
    const width = this.rail.clientWidth;
    const [a, b] = this.view;
    return b > a ? ((seconds - a) / (b - a)) * width : 0;
  }

  /** The key presses of a timeline: true when `event` was one (the caller prevents it). */
  handleKey(event) {
    if (event.ctrlKey || event.metaKey || event.altKey || !this.duration) return false;
    const second = this.fps ? Math.round(this.fps) : 30;
    switch (event.key) {
      case " ":
      case "Spacebar":
        this.setPlaying(!this.player.playing);
        return true;
      case "ArrowRight":
        this.step(event.shiftKey ? second : 1);
        return true;
      case "ArrowLeft":
        this.step(event.shiftKey ? -second : -1);
        return true;
      case "Home":
        this.scrubTo(0);
        return true;
      case "End":
        this.step(Number.MAX_SAFE_INTEGER);
        return true;
      case "+":
      case "=":
        if (!this.zoomable) return false;
        this.zoom(0.5);
        return true;
      case "-":
        if (!this.zoomable) return false;
        this.zoom(2);
        return true;
      default:
        return false;
    }
  }

  /**
   * The timeline's keys on the whole page (`target`), except where the focus is in a control
   * that uses them (a text box, a list) or on a button or link for Space/Enter; `extra`
   * maps more keys to actions. Returns the function that unbinds them.
   */
  bindKeys(target = document, extra = {}) {
    const handler = (event) => {
      if (event.defaultPrevented || typingIn(event.target) || this.node.hidden) return;
      const onControl = event.target instanceof Element && event.target.closest("button, a, summary");
      if (onControl && (event.key === " " || event.key === "Enter")) return; // it clicks itself
      if (!event.ctrlKey && !event.metaKey && !event.altKey && extra[event.key]) {
        extra[event.key](event);
        event.preventDefault();
        return;
      }
      if (this.handleKey(event)) event.preventDefault();
    };
    target.addEventListener("keydown", handler);
    return () => target.removeEventListener("keydown", handler);
  }

  update() {
    const time = this.player.time;
    const playing = this.player.playing;
    // A zoomed rail follows the playhead: when it leaves the part shown, the next part comes.
    const [a, b] = this.view;
    if (this.zoomable && this.zoomed && (time < a || time > b)) {
      const length = b - a;
      const start = playing ? time - 0.05 * length : time - length / 2;
      this.view = [Math.min(Math.max(0, start), this.duration - length), 0];
      this.view[1] = this.view[0] + length;
      this.notifyView();
    }
    const [from, to] = this.view;
    const fraction = to > from ? Math.min(1, Math.max(0, (time - from) / (to - from))) : 0;
    this.thumb.style.left = `${fraction * 100}%`;
    this.played.style.width = `${fraction * 100}%`;
    this.thumb.hidden = time < from - 1e-9 || time > to + 1e-9;
    this.playButton.textContent = playing ? "Pause" : "Play";
    this.playButton.setAttribute("aria-pressed", String(playing));
    let text = formatTime(time);
    if (this.fps && this.frameCount) {
      const frame = Math.min(this.frameCount - 1, this.firstFrame + Math.floor(time * this.fps + 1e-6));
      text = `frame ${frame + 1} / ${this.frameCount} · ${formatTime(time)} / ${formatTime(this.duration)}`;
      this.readout.dataset.frame = String(frame);
    }
    this.readout.textContent = text;
    this.rail.setAttribute("aria-valuenow", time.toFixed(2));
    this.rail.setAttribute("aria-valuetext", text);
    if (this.zoomable) {
      const whole = this.duration || 1;
      this.window.style.left = `${(100 * from) / whole}%`;
      this.window.style.width = `${Math.max(0.5, (100 * (to - from)) / whole)}%`;
      this.overview.firstChild.style.left = `${(100 * time) / whole}%`;
      this.viewFrom.textContent = formatTime(from);
      this.viewTo.textContent = formatTime(to);
      this.node.classList.toggle("is-zoomed", this.zoomed);
    }
  }

  dispose() {
    clearInterval(this.timer);
    this.resize.disconnect();
    this.viewListeners.clear();
  }
}
