// The Tessera monitor page: everything it shows comes from the API, with the token the
// user typed (sessionStorage: this tab only, gone when it closes). The job list and the
// workers are polled; a selected job's events arrive through its SSE stream, read with
// fetch() because EventSource cannot send an Authorization header.
"use strict";
(() => {
  const TOKEN_KEY = "tessera.token";
  const POLL_MS = 2000;
  const PREVIEW_MS = 1000;
  const FINAL = new Set(["done", "failed", "cancelled"]);
  const $ = (id) => document.getElementById(id);

  let pollTimer = null;
  let jobs = new Map();         // id -> last JobStatus
  const PAGE_SIZE = 50;
  let page = { offset: 0, more: false };
  const expanded = new Set();   // ids of the sequences shown with a row per frame
  let sequenceStatus = new Map(); // sequence id -> its SequenceStatus (every frame's state)
  let selected = null;          // { id, controller, state, denoise, loading, pending }

  class Unauthorized extends Error {}

  // ------------------------------------------------------------------ API access
  function authHeaders() {
    const token = sessionStorage.getItem(TOKEN_KEY);
    return token ? { Authorization: `Bearer ${token}` } : {};
  }

  async function api(path, options = {}) {
    const response = await fetch(path, {
      ...options, headers: { ...authHeaders(), ...(options.headers || {}) }, cache: "no-store",
    });
    if (response.status === 401) {
      showLogin(await problem(response));
      throw new Unauthorized();
    }
    return response;
  }

  // The API's error text: FastAPI's detail, a string or a list of validation errors.
  async function problem(response) {
    try {
      const body = await response.json();
      if (typeof body.detail === "string") return body.detail;
      if (Array.isArray(body.detail)) {
        return body.detail.map((e) => `${(e.loc || []).slice(1).join(".")}: ${e.msg}`).join("; ");
      }
      return JSON.stringify(body);
    } catch (e) {
      return `${response.status} ${response.statusText}`;
    }
  }

  // ------------------------------------------------------------------ sign-in
  function showLogin(message) {
    clearTimeout(pollTimer);
    pollTimer = null;
    closeStream();
    $("monitor").hidden = true;
    $("login").hidden = false;
    $("forget-token").hidden = true;
    $("login-error").textContent = sessionStorage.getItem(TOKEN_KEY) ? message : "";
    $("token").focus();
  }

  $("login").addEventListener("submit", (event) => {
    event.preventDefault();
    sessionStorage.setItem(TOKEN_KEY, $("token").value.trim());
    $("token").value = "";
    start();
  });

  $("forget-token").addEventListener("click", () => {
    sessionStorage.removeItem(TOKEN_KEY);
    showLogin("");
  });

  async function start() {
    try {
      await api("/jobs?limit=1");
    } catch (e) {
      if (!(e instanceof Unauthorized)) $("status").textContent = `cannot reach the API: ${e}`;
      return;
    }
    $("login").hidden = true;
    $("monitor").hidden = false;
    $("forget-token").hidden = !sessionStorage.getItem(TOKEN_KEY);
    poll();
  }

  // ------------------------------------------------------------------ job list and workers
  async function poll() {
    clearTimeout(pollTimer);
    try {
      const [jobsResponse, workersResponse] = await Promise.all([api(`/jobs?${listQuery()}`),
                                                                 api("/workers")]);
      if (jobsResponse.ok) {
        const list = await jobsResponse.json();
        page = { offset: list.offset, more: list.more };
        $("filter-error").textContent = "";
        // A frame range's strip shows all its frames, also those on other pages.
        const ids = [...new Set(list.jobs.filter((j) => j.sequence).map((j) => j.sequence))];
        const statuses = await Promise.all(ids.map(async (id) => {
          const response = await api(`/jobs/${id}`);
          return response.ok ? response.json() : null;
        }));
        sequenceStatus = new Map(statuses.filter(Boolean).map((status) => [status.id, status]));
        renderJobs(list.jobs);
      } else {
        $("filter-error").textContent = await problem(jobsResponse);
      }
      renderPager();
      if (workersResponse.ok) renderWorkers((await workersResponse.json()).workers);
      if (selected) refreshDetails(selected);
      $("status").textContent = `${jobs.size} jobs · updated ${new Date().toLocaleTimeString()}`;
    } catch (e) {
      if (e instanceof Unauthorized) return;
      $("status").textContent = `cannot reach the API: ${e}`;
    }
    pollTimer = setTimeout(poll, POLL_MS);
  }

  // The job list's filters (state, user, scene name) and page, as GET /jobs's query.
  function listQuery() {
    const params = new URLSearchParams({ limit: String(PAGE_SIZE), offset: String(page.offset) });
    for (const [name, id] of [["state", "filter-state"], ["user", "filter-user"], ["name", "filter-name"]]) {
      const value = $(id).value.trim();
      if (value) params.set(name, value);
    }
    return params.toString();
  }

  function renderPager() {
    const first = page.offset + 1;
    $("page-info").textContent = jobs.size ? `jobs ${first}–${page.offset + jobs.size}` : "no job";
    $("page-prev").disabled = page.offset === 0;
    $("page-next").disabled = !page.more;
  }

  $("filters").addEventListener("submit", (event) => {
    event.preventDefault();
    page.offset = 0;
    poll();
  });
  $("filter-state").addEventListener("change", () => { page.offset = 0; poll(); });
  $("page-prev").addEventListener("click", () => {
    page.offset = Math.max(0, page.offset - PAGE_SIZE);
    poll();
  });
  $("page-next").addEventListener("click", () => {
    page.offset += PAGE_SIZE;
    poll();
  });

  function progress(job) {
    if (job.state === "done") return 100;
    return job.tiles_total ? Math.floor((100 * job.tiles_done) / job.tiles_total) : 0;
  }

  function cell(row, text, className) {
    const td = row.insertCell();
    td.textContent = text;
    if (className) td.className = className;
    return td;
  }

  // One row per job; the frames of a frame range (jobs with the same `sequence`) share one
  // row with a strip of frame cells, one per frame coloured by its state, expanded on a
  // click into a row per frame.
  function renderJobs(list) {
    jobs = new Map(list.map((job) => [job.id, job]));
    const body = $("jobs").tBodies[0];
    body.replaceChildren();
    const sequences = new Map();
    for (const job of list) { // newest first: a retried frame's newest job stands for it
      if (!job.sequence) continue;
      if (!sequences.has(job.sequence)) sequences.set(job.sequence, []);
      const frames = sequences.get(job.sequence);
      if (!frames.some((f) => frameOf(f) === frameOf(job))) frames.push(job);
    }
    const shown = new Set();
    for (const job of list) {
      if (!job.sequence) {
        jobRow(body, job, job.scene_name);
        continue;
      }
      if (shown.has(job.sequence)) continue; // (and a retried frame's older jobs)
      shown.add(job.sequence);
      const status = sequenceStatus.get(job.sequence);
      const frames = status
        ? status.frames.map((f) => jobs.get(f.job) || frameOnly(f, status, job))
        : sequences.get(job.sequence).slice().sort((a, b) => frameOf(a) - frameOf(b));
      sequenceRow(body, job.sequence, frames);
      if (expanded.has(job.sequence)) {
        for (const frame of frames) {
          const row = jobRow(body, frame, `frame ${frameOf(frame)}`);
          row.classList.add("frame-row");
          row.dataset.sequence = job.sequence;
        }
      }
    }
    if (selected && jobs.has(selected.id)) showJob(jobs.get(selected.id));
  }

  // A frame whose job is not on this page: what the sequence's status says of it.
  function frameOnly(frame, status, listed) {
    return { id: frame.job, state: frame.state, scene_name: status.scene_name,
             settings: { frame: frame.frame }, tiles_done: frame.tiles_done,
             tiles_total: frame.tiles_total, passes_done: 0, priority: listed.priority,
             created_at: status.created_at, elapsed_seconds: null, render_seconds: null,
             warnings: status.warnings, partial: true };
  }

  function frameOf(job) {
    return job.settings && job.settings.frame !== null && job.settings.frame !== undefined
      ? Number(job.settings.frame) : 0;
  }

  const STATE_ORDER = ["running", "queued", "paused"];
  function combinedState(frames) {
    const states = frames.map((f) => f.state);
    for (const state of STATE_ORDER) if (states.includes(state)) return state;
    if (states.every((s) => s === "done")) return "done";
    return states.includes("failed") ? "failed" : "cancelled";
  }

  function sequenceRow(body, id, frames) {
    const row = body.insertRow();
    row.className = "sequence-row";
    row.dataset.sequence = id;
    const state = combinedState(frames);
    row.dataset.state = state;
    const name = cell(row, `${expanded.has(id) ? "▾" : "▸"} ${frames[0].scene_name} · `
                            + `${frames.length} frames`, "scene");
    name.title = "show or hide a row per frame";
    cell(row, id.slice(0, 8));
    cell(row, state, `state state-${state}`);
    const strip = cell(row, "", "frames");
    for (const frame of frames) {
      const box = document.createElement("span");
      box.className = `frame-cell state-bg-${frame.state}`;
      box.dataset.frame = String(frameOf(frame));
      box.dataset.state = frame.state;
      box.dataset.job = frame.id;
      box.title = `frame ${frameOf(frame)}: ${frame.state} (${progress(frame)} %)`;
      box.textContent = String(frameOf(frame));
      box.addEventListener("click", (event) => {
        event.stopPropagation();
        select(frame.id);
      });
      strip.append(box);
    }
    const done = frames.reduce((n, f) => n + f.tiles_done, 0);
    const total = frames.reduce((n, f) => n + f.tiles_total, 0);
    strip.dataset.percent = String(total ? Math.floor((100 * done) / total) : 0);
    cell(row, String(frames[0].priority), "priority");
    cell(row, new Date(frames[0].created_at).toLocaleTimeString());
    cell(row, "");
    cell(row, frames.some((f) => f.partial) ? ""
      : `${frames.reduce((t, f) => t + f.render_seconds, 0).toFixed(1)} s`);
    const warnings = frames[0].warnings;
    cell(row, warnings.length ? `${warnings.length} ⚠` : "", "warnings");
    row.title = warnings.join("\n");
    row.addEventListener("click", () => {
      if (expanded.has(id)) expanded.delete(id);
      else expanded.add(id);
      renderJobs([...jobs.values()]);
    });
  }

  function jobRow(body, job, label) {
    const row = body.insertRow();
    row.dataset.job = job.id;
    row.dataset.state = job.state;
    if (selected && selected.id === job.id) row.classList.add("selected");
    cell(row, label, "scene");
    cell(row, job.id.slice(0, 8));
    cell(row, job.state, `state state-${job.state}`);
    const pct = progress(job);
    const td = cell(row, "", "progress");
    const bar = document.createElement("progress");
    bar.max = 100;
    bar.value = pct;
    // A noise-target job's tiles finish only when they converge: its passes show progress.
    const passes = job.settings && job.settings.target_error ? ` · ${job.passes_done} passes` : "";
    td.append(bar, ` ${pct} %${passes}`);
    td.dataset.percent = pct;
    cell(row, String(job.priority), "priority");
    cell(row, new Date(job.created_at).toLocaleTimeString());
    cell(row, job.partial ? "" : `${job.elapsed_seconds.toFixed(1)} s`);
    cell(row, job.partial ? "" : `${job.render_seconds.toFixed(1)} s`);
    cell(row, job.warnings.length ? `${job.warnings.length} ⚠` : "", "warnings");
    row.title = job.warnings.join("\n");
    row.addEventListener("click", () => select(job.id));
    return row;
  }

  function renderWorkers(list) {
    const body = $("workers").tBodies[0];
    body.replaceChildren();
    for (const worker of list) {
      const row = body.insertRow();
      row.dataset.worker = worker.name;
      cell(row, worker.name);
      cell(row, `${worker.host} (pid ${worker.pid})`);
      const age = Math.max(0, (Date.now() - Date.parse(worker.last_heartbeat)) / 1000);
      cell(row, `${new Date(worker.last_heartbeat).toLocaleTimeString()} (${age.toFixed(0)} s ago)`);
      cell(row, (worker.current || "idle") + (worker.disabled ? " · disabled" : ""), "current");
      cell(row, String(worker.tiles_done));
      cell(row, String(worker.failures), worker.failures ? "error" : "");
      row.dataset.disabled = String(worker.disabled);
      // Admins only: the API answers 403 to anyone else, shown beside the buttons.
      const actions = cell(row, "", "actions");
      actions.append(
        workerButton(worker.name, worker.disabled ? "enable" : "disable", "POST",
                     `/workers/${encodeURIComponent(worker.name)}/${worker.disabled ? "enable" : "disable"}`),
        workerButton(worker.name, "clear blocklist", "DELETE",
                     `/workers/${encodeURIComponent(worker.name)}/blocklist`));
    }
    if (!list.length) {
      const row = body.insertRow();
      const td = cell(row, "no live worker");
      td.colSpan = 7;
    }
  }

  function workerButton(name, label, method, path) {
    const button = document.createElement("button");
    button.type = "button";
    button.textContent = label;
    button.dataset.action = label;
    button.addEventListener("click", async () => {
      try {
        const response = await api(path, { method });
        if (response.ok) {
          const body = await response.json();
          $("worker-result").textContent = body.jobs
            ? `${name}: taken off the blocklist of ${body.jobs.length} job(s)`
            : `${name}: ${body.disabled ? "disabled" : "enabled"}`;
          poll();
        } else {
          $("worker-result").textContent = `${name}: ${await problem(response)}`;
        }
      } catch (e) {
        if (!(e instanceof Unauthorized)) $("worker-result").textContent = String(e);
      }
    });
    return button;
  }

  // ------------------------------------------------------------------ the selected job
  function select(id) {
    if (selected && selected.id === id) return;
    closeStream();
    selected = { id, controller: new AbortController(), state: null, denoise: false,
                 loading: false, pending: false, progressEvents: 0,
                 details: { loading: false, pending: false, final: false } };
    for (const row of $("jobs").tBodies[0].rows) {
      row.classList.toggle("selected", row.dataset.job === id);
    }
    $("job-section").hidden = false;
    $("job-id").textContent = id;
    $("events").replaceChildren();
    $("tasks").tBodies[0].replaceChildren();
    $("tasks-summary").textContent = "";
    $("log").textContent = "";
    delete $("log").dataset.lines;
    $("download-exr").hidden = true;
    $("control-result").textContent = "";
    for (const img of [$("preview"), $("denoised")]) {
      img.removeAttribute("src");
      img.dataset.loads = "0";
      delete img.dataset.state;
      delete img.dataset.events;
    }
    if (jobs.has(id)) showJob(jobs.get(id));
    followEvents(selected);
    refreshPreviews();
    refreshDetails(selected);
  }

  function closeStream() {
    if (selected) selected.controller.abort();
  }

  function showJob(job) {
    if (!selected || selected.id !== job.id) return;
    // A list fetched before the final state event must not undo it.
    if (!FINAL.has(selected.state)) selected.state = job.state;
    selected.denoise = Boolean(job.settings && job.settings.denoise);
    const state = $("job-state");
    state.textContent = job.state;
    state.className = `state state-${job.state}`;
    state.dataset.state = job.state;
    if (document.activeElement !== $("priority")) $("priority").value = job.priority;
    const at = (t) => (t ? new Date(t).toLocaleTimeString() : "–");
    $("job-times").textContent = `${job.scene_name}, ${job.settings.width}×${job.settings.height}, `
      + `${job.settings.integrator}; submitted ${at(job.created_at)}, started ${at(job.started_at)}, `
      + `finished ${at(job.finished_at)}; ${job.tiles_done}/${job.tiles_total} tiles, `
      + `${job.passes_done} passes, ${job.render_seconds.toFixed(1)} s rendering`;
    $("job-error").textContent = job.error || "";
    $("job-warnings").replaceChildren(...job.warnings.map((w) => {
      const li = document.createElement("li");
      li.textContent = w;
      return li;
    }));
    $("denoised-figure").hidden = !selected.denoise;
    const final = FINAL.has(job.state);
    $("pause").disabled = final || job.state === "paused";
    $("resume").disabled = job.state !== "paused";
    $("cancel").disabled = final;
    $("set-priority").disabled = final;
    $("retry").disabled = !(job.state === "failed" || job.state === "cancelled");
    $("download-exr").hidden = job.state !== "done";
  }

  // Reads the job's SSE stream until it ends (after the final state), resuming after the
  // last event id when the connection drops.
  async function followEvents(job) {
    let after = null;
    while (!job.controller.signal.aborted) {
      try {
        const query = after ? `?after=${encodeURIComponent(after)}` : "";
        const response = await api(`/jobs/${job.id}/events${query}`,
                                   { signal: job.controller.signal });
        if (!response.ok) {
          logEvent(job, "error", await problem(response));
          return;
        }
        const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
        let buffer = "";
        for (;;) {
          const { value, done } = await reader.read();
          if (done) return; // the server ends the stream after the job's final state
          buffer += value.replace(/\r\n?/g, "\n");
          let end;
          while ((end = buffer.indexOf("\n\n")) >= 0) {
            const message = parseMessage(buffer.slice(0, end));
            buffer = buffer.slice(end + 2);
            if (message.id) after = message.id;
            if (message.data) onEvent(job, message.event, JSON.parse(message.data), eventTime(message.id));
          }
        }
      } catch (e) {
        if (job.controller.signal.aborted || e instanceof Unauthorized) return;
        logEvent(job, "error", `events stream interrupted (${e}); reconnecting`);
        await new Promise((resolve) => setTimeout(resolve, POLL_MS));
      }
    }
  }

  function parseMessage(block) {
    const message = { event: "message", data: "", id: null };
    for (const line of block.split("\n")) {
      if (!line || line.startsWith(":")) continue; // a comment: the keep-alive
      const colon = line.indexOf(":");
      const field = colon < 0 ? line : line.slice(0, colon);
      const value = colon < 0 ? "" : line.slice(colon + 1).replace(/^ /, "");
      if (field === "event") message.event = value;
      else if (field === "data") message.data += value;
      else if (field === "id") message.id = value;
    }
    return message;
  }

  // When an event happened: its stream id is "MS-SEQ", MS the millisecond Redis stored it
  // (a replayed stream shows the job's own times, not the moment the page read them).
  function eventTime(id) {
    const ms = id ? Number(id.split("-")[0]) : NaN;
    return Number.isFinite(ms) ? new Date(ms) : null;
  }

  function onEvent(job, type, event, at) {
    if (selected !== job) return;
    const parts = [];
    if (event.state) parts.push(event.state);
    if (event.tile !== undefined) parts.push(`tile ${event.tile}`);
    if (event.pass_index !== undefined) parts.push(`pass ${event.pass_index}`);
    if (event.samples !== undefined) parts.push(`${event.samples} spp`);
    if (event.tiles_done !== undefined) parts.push(`${event.tiles_done} tiles done`);
    if (event.worker !== undefined) parts.push(`on ${event.worker}`);
    if (event.seconds !== undefined) parts.push(`${Number(event.seconds).toFixed(3)} s`);
    if (event.message) parts.push(event.message);
    logEvent(job, type, parts.join(", "), at);
    if (type === "state") {
      job.state = event.state;
      const known = jobs.get(job.id);
      if (known) showJob({ ...known, state: event.state });
      poll();
    }
    if (type === "state" || type === "failure") refreshDetails(job);
    if (type === "tile" || type === "pass" || type === "scene_pass") job.progressEvents += 1;
    if (type === "state" || type === "tile" || type === "pass" || type === "scene_pass") {
      refreshPreviews();
    }
  }

  function logEvent(job, type, text, at) {
    if (selected !== job) return;
    const li = document.createElement("li");
    li.dataset.type = type;
    const when = at || new Date(); // the page's own notes (a dropped stream) have no event time
    li.dataset.time = when.toISOString();
    li.textContent = `${timeOfDay(when)} ${type}: ${text}`;
    const list = $("events");
    list.append(li);
    list.scrollTop = list.scrollHeight;
  }

  // hh:mm:ss.mmm in the browser's time zone: events of one tile pass are milliseconds apart.
  function timeOfDay(date) {
    const pad = (n, w = 2) => String(n).padStart(w, "0");
    return `${pad(date.getHours())}:${pad(date.getMinutes())}:${pad(date.getSeconds())}`
      + `.${pad(date.getMilliseconds(), 3)}`;
  }

  // ------------------------------------------------------------------ tasks and log
  // The selected job's task table and log, one fetch of each at a time: refreshed with
  // the list's poll while the job runs, on its state and failure events, and once more
  // after it is final (then no more).
  async function refreshDetails(job) {
    const d = job.details;
    if (d.final) return;
    if (d.loading) {
      d.pending = true;
      return;
    }
    d.loading = true;
    try {
      do {
        d.pending = false;
        const finalNow = FINAL.has(job.state);
        const [tasks, log] = await Promise.all([api(`/jobs/${job.id}/tasks`, { signal: job.controller.signal }),
                                                api(`/jobs/${job.id}/log`, { signal: job.controller.signal })]);
        if (selected !== job) return;
        if (!jobs.has(job.id) || jobs.get(job.id).partial) {
          const status = await api(`/jobs/${job.id}`, { signal: job.controller.signal });
          if (status.ok && selected === job) showJob(await status.json());
        }
        if (tasks.ok) renderTasks(await tasks.json());
        if (log.ok) renderLog((await log.json()).lines);
        if (finalNow && tasks.ok && log.ok) d.final = true;
      } while (d.pending && !d.final && selected === job);
    } catch (e) {
      // aborted (another job selected) or unauthorised: nothing to show
    } finally {
      d.loading = false;
    }
  }

  function renderTasks(table) {
    const body = $("tasks").tBodies[0];
    body.replaceChildren();
    const secs = (v) => (v === null || v === undefined ? "" : `${Number(v).toFixed(3)} s`);
    const rows = [...table.scene_passes, ...table.tiles];
    for (const task of rows) {
      const row = body.insertRow();
      row.dataset.kind = task.kind;
      row.dataset.index = String(task.index);
      row.dataset.state = task.state;
      row.dataset.slow = String(task.slow);
      if (task.slow) row.classList.add("slow");
      if (task.state === "failed") row.classList.add("failed");
      cell(row, task.kind === "tile" ? `tile ${task.index}` : `scene pass ${task.index}`);
      cell(row, task.kind === "tile" ? `${task.x0},${task.y0} ${task.width}×${task.height}` : "");
      cell(row, task.slow ? `${task.state} (slow)` : task.state, `state state-${task.state}`);
      cell(row, task.worker || "", "worker");
      cell(row, task.passes_done ? `${task.passes_done}` : "");
      cell(row, task.samples === null ? "" : String(task.samples));
      cell(row, String(task.attempts), task.attempts ? "attempts error" : "attempts");
      cell(row, task.state === "rendering" ? `${secs(task.rendering_seconds)} so far` : secs(task.render_seconds));
      cell(row, task.finished_at ? timeOfDay(new Date(task.finished_at)) : "");
      const error = cell(row, task.last_error || "", "error");
      error.title = task.last_error || "";
    }
    const count = (state) => rows.filter((t) => t.state === state).length;
    const median = table.median_pass_seconds === null ? "–" : `${table.median_pass_seconds.toFixed(3)} s`;
    $("tasks-summary").textContent = `${count("done")} done, ${count("rendering")} rendering, `
      + `${count("queued")} queued, ${count("failed")} failed, ${rows.filter((t) => t.slow).length} slow `
      + `(over ${table.slow_factor}× the median pass, ${median}, and ${table.slow_min_excess} s more)`
      + (table.events_complete ? "" : "; older passes' workers and times were trimmed");
  }

  function renderLog(lines) {
    const log = $("log");
    const atEnd = log.scrollTop + log.clientHeight >= log.scrollHeight - 4;
    log.textContent = lines.join("\n");
    log.dataset.lines = String(lines.length);
    if (atEnd) log.scrollTop = log.scrollHeight;
  }

  // One preview request at a time, at most one a second: events that land meanwhile ask
  // for one more, so a job with many tiles does not make the server merge per tile.
  async function refreshPreviews() {
    const job = selected;
    if (!job) return;
    if (job.loading) {
      job.pending = true;
      return;
    }
    job.loading = true;
    try {
      do {
        const began = Date.now();
        job.pending = false;
        const seen = { state: job.state, events: job.progressEvents };
        await loadImage(job, $("preview"), "preview.png", seen);
        if (job.denoise) await loadImage(job, $("denoised"), "denoised.png", seen);
        if (job.pending) {
          await new Promise((resolve) => setTimeout(resolve, Math.max(0, PREVIEW_MS - (Date.now() - began))));
        }
      } while (job.pending && selected === job);
    } finally {
      job.loading = false;
    }
  }

  // `seen` is what the page knew when the request was made: the job's state (an image
  // fetched once the job is final is its final preview) and how many passes had landed.
  // The image's data-state and data-events say so.
  async function loadImage(job, img, name, seen) {
    let response;
    try {
      response = await api(`/jobs/${job.id}/${name}`, { signal: job.controller.signal });
    } catch (e) {
      return;
    }
    if (!response.ok || selected !== job) return; // 409: no image (yet, or ever)
    const url = URL.createObjectURL(await response.blob());
    await new Promise((resolve) => {
      img.onload = img.onerror = resolve;
      const old = img.src;
      img.src = url;
      if (old.startsWith("blob:")) URL.revokeObjectURL(old);
    });
    img.dataset.loads = String(Number(img.dataset.loads) + 1);
    if (seen.state) img.dataset.state = seen.state;
    img.dataset.events = String(seen.events);
  }

  // ------------------------------------------------------------------ controls
  async function control(method, path, body) {
    if (!selected) return;
    const job = selected;
    const options = { method };
    if (body !== undefined) {
      options.headers = { "Content-Type": "application/json" };
      options.body = JSON.stringify(body);
    }
    try {
      const response = await api(`/jobs/${job.id}${path}`, options);
      if (response.ok) {
        const status = await response.json();
        $("control-result").textContent = `${status.state}, priority ${status.priority}`;
        jobs.set(status.id, status);
        showJob(status);
        poll();
      } else {
        $("control-result").textContent = await problem(response);
      }
    } catch (e) {
      if (!(e instanceof Unauthorized)) $("control-result").textContent = String(e);
    }
  }

  $("pause").addEventListener("click", () => control("POST", "/pause"));
  $("resume").addEventListener("click", () => control("POST", "/resume"));
  $("cancel").addEventListener("click", () => control("DELETE", ""));
  $("retry").addEventListener("click", async () => {
    if (!selected) return;
    const response = await api(`/jobs/${selected.id}/retry`, { method: "POST" });
    if (response.ok) {
      const created = await response.json();
      $("control-result").textContent = `retried as job ${created.id.slice(0, 8)}`;
      $("control-result").dataset.retried = created.id;
      await poll();
      select(created.id);
    } else {
      $("control-result").textContent = await problem(response);
    }
  });

  // Delete: cancel first when it still runs, then remove it with everything it keeps.
  $("delete").addEventListener("click", async () => {
    if (!selected) return;
    const id = selected.id;
    if (!FINAL.has(selected.state)) {
      const cancelled = await api(`/jobs/${id}`, { method: "DELETE" });
      if (!cancelled.ok) {
        $("control-result").textContent = await problem(cancelled);
        return;
      }
    }
    const response = await api(`/jobs/${id}/purge`, { method: "POST" });
    if (response.ok) {
      closeStream();
      selected = null;
      $("job-section").hidden = true;
      $("status").dataset.deleted = id;
      poll();
    } else {
      $("control-result").textContent = await problem(response);
    }
  });

  // The EXR is behind the token: fetched like everything else, then saved from a blob: URL.
  $("download-exr").addEventListener("click", async (event) => {
    event.preventDefault();
    if (!selected) return;
    const id = selected.id;
    const response = await api(`/jobs/${id}/image.exr`);
    if (!response.ok) {
      $("control-result").textContent = await problem(response);
      return;
    }
    const blob = await response.blob();
    const link = document.createElement("a");
    link.href = URL.createObjectURL(blob);
    link.download = `${id}.exr`;
    document.body.append(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(link.href), 60000);
    $("download-exr").dataset.bytes = String(blob.size);
  });

  $("set-priority").addEventListener("click",
    () => control("POST", "/priority", { priority: Number($("priority").value) }));

  // ------------------------------------------------------------------ upload
  const drop = $("drop");
  drop.addEventListener("dragover", (event) => {
    event.preventDefault();
    drop.classList.add("over");
  });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (event) => {
    event.preventDefault();
    drop.classList.remove("over");
    if (event.dataTransfer.files.length) {
      $("file").files = event.dataTransfer.files;
      showFileName();
    }
  });
  function showFileName() {
    const file = $("file").files[0];
    $("file-name").textContent = file ? `${file.name} (${file.size} bytes)` : "";
  }
  $("file").addEventListener("change", showFileName);

  $("upload").addEventListener("submit", async (event) => {
    event.preventDefault();
    const form = new FormData($("upload"));
    for (const [name, value] of [...form.entries()]) {
      if (value === "") form.delete(name); // blank: the server's default (the scene's)
    }
    $("submit").disabled = true;
    $("upload-result").textContent = "uploading…";
    try {
      const response = await api("/jobs", { method: "POST", body: form });
      if (response.ok) {
        const created = await response.json();
        $("upload-result").textContent = `submitted job ${created.id.slice(0, 8)}: `
          + `${created.width}×${created.height}, ${created.tiles_total} tiles`;
        $("upload-result").dataset.job = created.id;
        await poll();
        select(created.id);
      } else {
        $("upload-result").textContent = `refused: ${await problem(response)}`;
      }
    } catch (e) {
      if (!(e instanceof Unauthorized)) $("upload-result").textContent = String(e);
    } finally {
      $("submit").disabled = false;
    }
  });

  start();
})();
