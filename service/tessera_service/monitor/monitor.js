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
      const [jobsResponse, workersResponse] = await Promise.all([api("/jobs?limit=100"),
                                                                 api("/workers")]);
      if (jobsResponse.ok) renderJobs((await jobsResponse.json()).jobs);
      if (workersResponse.ok) renderWorkers((await workersResponse.json()).workers);
      $("status").textContent = `${jobs.size} jobs · updated ${new Date().toLocaleTimeString()}`;
    } catch (e) {
      if (e instanceof Unauthorized) return;
      $("status").textContent = `cannot reach the API: ${e}`;
    }
    pollTimer = setTimeout(poll, POLL_MS);
  }

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

  function renderJobs(list) {
    jobs = new Map(list.map((job) => [job.id, job]));
    const body = $("jobs").tBodies[0];
    body.replaceChildren();
    for (const job of list) {
      const row = body.insertRow();
      row.dataset.job = job.id;
      row.dataset.state = job.state;
      if (selected && selected.id === job.id) row.classList.add("selected");
      cell(row, job.scene_name);
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
      cell(row, `${job.elapsed_seconds.toFixed(1)} s`);
      cell(row, `${job.render_seconds.toFixed(1)} s`);
      cell(row, job.warnings.length ? `${job.warnings.length} ⚠` : "", "warnings");
      row.title = job.warnings.join("\n");
      row.addEventListener("click", () => select(job.id));
    }
    if (selected && jobs.has(selected.id)) showJob(jobs.get(selected.id));
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
      cell(row, worker.current || "idle", "current");
      cell(row, String(worker.tiles_done));
      cell(row, String(worker.failures), worker.failures ? "error" : "");
    }
    if (!list.length) {
      const row = body.insertRow();
      const td = cell(row, "no live worker");
      td.colSpan = 6;
    }
  }

  // ------------------------------------------------------------------ the selected job
  function select(id) {
    if (selected && selected.id === id) return;
    closeStream();
    selected = { id, controller: new AbortController(), state: null, denoise: false,
                 loading: false, pending: false, progressEvents: 0 };
    for (const row of $("jobs").tBodies[0].rows) {
      row.classList.toggle("selected", row.dataset.job === id);
    }
    $("job-section").hidden = false;
    $("job-id").textContent = id;
    $("events").replaceChildren();
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
            if (message.data) onEvent(job, message.event, JSON.parse(message.data));
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

  function onEvent(job, type, event) {
    if (selected !== job) return;
    const parts = [];
    if (event.state) parts.push(event.state);
    if (event.tile !== undefined) parts.push(`tile ${event.tile}`);
    if (event.pass_index !== undefined) parts.push(`pass ${event.pass_index}`);
    if (event.samples !== undefined) parts.push(`${event.samples} spp`);
    if (event.tiles_done !== undefined) parts.push(`${event.tiles_done} tiles done`);
    if (event.message) parts.push(event.message);
    logEvent(job, type, parts.join(", "));
    if (type === "state") {
      job.state = event.state;
      const known = jobs.get(job.id);
      if (known) showJob({ ...known, state: event.state });
      poll();
    }
    if (type === "tile" || type === "pass" || type === "scene_pass") job.progressEvents += 1;
    if (type === "state" || type === "tile" || type === "pass" || type === "scene_pass") {
      refreshPreviews();
    }
  }

  function logEvent(job, type, text) {
    if (selected !== job) return;
    const li = document.createElement("li");
    li.dataset.type = type;
    li.textContent = `${new Date().toLocaleTimeString()} ${type}: ${text}`;
    const list = $("events");
    list.append(li);
    list.scrollTop = list.scrollHeight;
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
