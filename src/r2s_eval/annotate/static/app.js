// The annotation page: two rollout videos on one clock, keyboard answers saved one by one.
"use strict";

const $ = (id) => document.getElementById(id);
const videos = { A: null, B: null };
const SPEEDS = [1, 0.5, 0.25];
const state = {
  annotator: null, total: 0, position: 0, item: null, shownAt: 0,
  watched: { A: false, B: false }, busy: false, speed: 0,
};

function setState(name) { document.body.dataset.state = name; }

async function api(path, options) {
  const response = await fetch(path, { cache: "no-store", ...options });
  let body = null;
  try { body = await response.json(); } catch (err) { body = null; }
  if (!response.ok) throw new Error((body && body.error) || `the server answered ${response.status}`);
  return body;
}

function show(section) {
  for (const id of ["login", "pair", "done"]) $(id).hidden = id !== section;
}

function showProgress(answered, total) {
  $("progress").hidden = false;
  $("progress-text").textContent = `${answered} / ${total}`;
  $("progress-fill").style.width = total ? `${(100 * answered) / total}%` : "0";
  document.body.dataset.answered = String(answered);
}

// ------------------------------------------------------------------ videos on one clock

function clock() { return Math.max(videos.A.currentTime || 0, videos.B.currentTime || 0); }
function fps() { return (state.item && Math.min(state.item.fps_a, state.item.fps_b)) || 10; }
function bothPaused() { return videos.A.paused && videos.B.paused; }
function bothEnded() { return videos.A.ended && videos.B.ended; }

function showClock() {
  const t = clock();
  $("time").textContent = `${t.toFixed(2)} s`;
  $("frame").textContent = String(Math.round(t * fps()));
}

async function playBoth() {
  const pending = [];
  for (const v of [videos.A, videos.B]) {
    if (!(v.ended || (v.duration && v.currentTime >= v.duration))) pending.push(v.play());
  }
  try { await Promise.all(pending); } catch (err) { /* a newer load or pause interrupted play() */ }
}

function pauseBoth() { videos.A.pause(); videos.B.pause(); }

function seekBoth(t) {
  for (const v of [videos.A, videos.B]) {
    const end = Number.isFinite(v.duration) ? Math.max(0, v.duration - 1e-3) : t;
    v.currentTime = Math.min(Math.max(0, t), end);
  }
  showClock();
}

function replay() { pauseBoth(); seekBoth(0); playBoth(); }

function togglePlay() {
  if (bothEnded()) return replay();
  if (bothPaused() || videos.A.paused !== videos.B.paused) {
    // Re-align before resuming, so a step or seek on one clock leaves them together.
    seekBoth(clock());
    return playBoth();
  }
  pauseBoth();
}

function step(direction) { pauseBoth(); seekBoth(clock() + direction / fps()); }

function cycleSpeed() {
  state.speed = (state.speed + 1) % SPEEDS.length;
  for (const v of [videos.A, videos.B]) v.playbackRate = SPEEDS[state.speed];
  $("speed-value").textContent = `${SPEEDS[state.speed]}\u00d7`;
}

// While both play, B follows A's clock; once one of them has ended, the other plays on alone.
function followClock() {
  const a = videos.A, b = videos.B;
  if (!a.paused && !b.paused && !a.ended && !b.ended && Math.abs(a.currentTime - b.currentTime) > 0.5 / fps()) {
    b.currentTime = a.currentTime;
  }
  showClock();
  requestAnimationFrame(followClock);
}

// ---------------------------------------------------------------------------- items

async function load(position) {
  setState("loading");
  const item = await api(`/api/item?annotator=${encodeURIComponent(state.annotator)}&position=${position}`);
  state.item = item;
  state.position = item.position;
  state.watched = { A: false, B: false };
  state.shownAt = performance.now();
  $("instruction").textContent = item.instruction;
  for (const [letter, src] of [["A", item.video_a], ["B", item.video_b]]) {
    const v = videos[letter];
    v.src = src;
    v.playbackRate = SPEEDS[state.speed];
  }
  for (const letter of ["A", "B"]) {
    $(`choose-${letter.toLowerCase()}`).classList.toggle("selected", item.choice === letter);
  }
  document.body.dataset.position = String(item.position);
  $("status").textContent = item.choice ? `Pair ${item.position + 1}: you answered ${item.choice} (press A or B to change it).` : "";
  $("status").className = "status";
  showProgress(item.answered, item.total);
  show("pair");
  setState("ready");
  playBoth();
}

async function answer(choice) {
  if (state.busy || !state.item || document.body.dataset.state !== "ready") return;
  state.busy = true;
  setState("saving");
  const body = {
    annotator: state.annotator, position: state.position, choice,
    seconds: (performance.now() - state.shownAt) / 1000, watched_full: state.watched.A && state.watched.B,
  };
  let progress;
  try {
    progress = await api("/api/answer", {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
    });
  } catch (err) {
    $("status").textContent = `Not saved (${err.message}); press ${choice} again to retry.`;
    $("status").className = "status error";
    setState("ready");
    state.busy = false;
    return;
  }
  // The answer is on the server's disk from here on; only loading the next pair may still go wrong.
  showProgress(progress.answered, progress.total);
  try {
    if (progress.position >= progress.total) {
      pauseBoth();
      show("done");
      setState("done");
    } else {
      await load(progress.position);
      $("status").textContent = `Saved: ${choice} for pair ${body.position + 1}.`;
    }
  } catch (err) {
    $("status").textContent = `Saved: ${choice} for pair ${body.position + 1}, but the next pair did not load `
      + `(${err.message}); press N to load it.`;
    $("status").className = "status error";
    setState("stalled");
  } finally {
    state.busy = false;
  }
}

async function previous() {
  const target = document.body.dataset.state === "done" ? state.total - 1 : state.position - 1;
  if (target >= 0 && !state.busy) await load(target);
}

async function firstUnanswered() {
  const progress = await api(`/api/progress?annotator=${encodeURIComponent(state.annotator)}`);
  if (progress.position < progress.total) await load(progress.position);
}

// ------------------------------------------------------------------------ annotator

async function begin(name) {
  const progress = await api(`/api/progress?annotator=${encodeURIComponent(name)}`);
  state.annotator = progress.annotator;
  state.total = progress.total;
  localStorage.setItem("r2s-annotator", state.annotator);
  const url = new URL(window.location.href);
  url.searchParams.set("annotator", state.annotator);
  history.replaceState(null, "", url);
  $("annotator-name").textContent = state.annotator;
  $("who").hidden = false;
  showProgress(progress.answered, progress.total);
  if (progress.position >= progress.total) {
    show("done");
    setState("done");
  } else {
    await load(progress.position);
  }
}

function askName(message) {
  show("login");
  setState("login");
  $("login-error").textContent = message || "";
  $("login-name").focus();
}

function onKey(event) {
  if (event.target instanceof HTMLInputElement || event.ctrlKey || event.metaKey || event.altKey) return;
  const key = event.key.length === 1 ? event.key.toLowerCase() : event.key;
  const pairShown = !$("pair").hidden;
  const actions = {
    a: () => answer("A"), b: () => answer("B"),
    " ": pairShown && togglePlay, r: pairShown && replay, s: pairShown && cycleSpeed,
    ArrowLeft: pairShown && (() => step(-1)), ",": pairShown && (() => step(-1)),
    ArrowRight: pairShown && (() => step(1)), ".": pairShown && (() => step(1)),
    Backspace: previous, n: firstUnanswered,
  };
  const action = state.annotator && actions[key];
  if (!action) return;
  event.preventDefault();
  if (document.activeElement instanceof HTMLButtonElement) document.activeElement.blur();
  action();
}

async function init() {
  videos.A = $("video-a");
  videos.B = $("video-b");
  for (const [letter, v] of Object.entries(videos)) {
    v.addEventListener("ended", () => { state.watched[letter] = true; });
  }
  const info = await api("/api/info");
  state.total = info.total;
  $("question").textContent = info.question;
  for (const c of info.criteria) {
    const li = document.createElement("li");
    const name = document.createElement("strong");
    name.textContent = c.name;
    li.append(name, ` \u2014 ${c.text}`);
    $("criteria").append(li);
  }
  $("play").addEventListener("click", togglePlay);
  $("replay").addEventListener("click", replay);
  $("step-back").addEventListener("click", () => step(-1));
  $("step-forward").addEventListener("click", () => step(1));
  $("speed").addEventListener("click", cycleSpeed);
  $("choose-a").addEventListener("click", () => answer("A"));
  $("choose-b").addEventListener("click", () => answer("B"));
  $("switch").addEventListener("click", () => {
    localStorage.removeItem("r2s-annotator");
    window.location.search = "";
  });
  $("login-form").addEventListener("submit", (event) => {
    event.preventDefault();
    begin($("login-name").value.trim()).catch((err) => askName(err.message));
  });
  document.addEventListener("keydown", onKey);
  requestAnimationFrame(followClock);
  const name = new URLSearchParams(window.location.search).get("annotator") || localStorage.getItem("r2s-annotator");
  if (name) await begin(name).catch((err) => askName(err.message));
  else askName();
}

document.addEventListener("DOMContentLoaded", () => {
  init().catch((err) => {
    document.body.dataset.state = "error";
    document.querySelector("main").textContent = `The annotation page could not start: ${err.message}`;
  });
});
