// cellctl station: live updates by server-sent events, and actions with the token. No framework.
(function () {
  "use strict";
  const tokenBox = document.getElementById("token");
  if (tokenBox) {
    tokenBox.value = localStorage.getItem("cellctl-token") || "";
    tokenBox.addEventListener("change", () => localStorage.setItem("cellctl-token", tokenBox.value));
  }

  function setTile(id, text, cls) {
    const el = document.getElementById(id);
    if (!el) return;
    el.textContent = text;
    el.className = "v " + cls;
  }

  function showState(s) {
    const badge = document.getElementById("phase-badge");
    if (badge) { badge.textContent = s.phase.toUpperCase(); badge.className = "badge phase-" + s.phase; }
    setTile("t-phase", s.phase.toUpperCase() + (s.cycle ? " · cycle " + s.cycle : ""), "phase-text phase-" + s.phase);
    setTile("t-cameras", s.cameras_ok ? "OK" : "NOT OK", s.cameras_ok ? "ok" : "bad");
    setTile("t-calibration", s.calibration_ok ? "OK" : "NOT OK", s.calibration_ok ? "ok" : "bad");  // why: the calibration page
    if (s.plc_clients !== null) setTile("t-plc", s.plc_clients ? "CONNECTED (" + s.plc_clients + ")" : "NO CLIENT", s.plc_clients ? "ok" : "warn");
    if (s.heartbeat_ok !== null) setTile("t-heartbeat", s.heartbeat_ok ? "RUNNING" : "STALLED", s.heartbeat_ok ? "ok" : "bad");
    setTile("t-cycles", String(s.cycles_done), "");
    if (s.recipe) setTile("t-recipe", s.recipe[0] + " · " + s.recipe[1], "");
  }

  const last = document.getElementById("last");
  if (document.body.dataset.page === "cell" && window.EventSource) {
    const source = new EventSource("/events");
    source.onmessage = async (message) => {
      const s = JSON.parse(message.data);
      showState(s);
      if (last && String(s.cycle_version) !== last.dataset.cycleVersion) {
        const reply = await fetch("/fragments/last", { cache: "no-store" });
        if (reply.ok) { last.innerHTML = await reply.text(); last.dataset.cycleVersion = String(s.cycle_version); }
      }
    };
  }

  document.querySelectorAll("button[data-action]").forEach((button) => {
    button.addEventListener("click", async () => {
      const out = document.getElementById("action-result");
      const headers = {};
      const token = tokenBox ? tokenBox.value.trim() : "";
      if (token) headers["Authorization"] = "Bearer " + token;
      button.disabled = true;
      out.className = "action-result";
      out.textContent = "working…";
      try {
        const reply = await fetch(button.dataset.action, { method: "POST", headers: headers });
        const body = await reply.json();
        if (!reply.ok) { out.className = "action-result refused"; out.textContent = body.error; return; }
        out.className = "action-result done";
        if (body.summary !== undefined) {
          out.textContent = body.summary;
          const img = document.getElementById("rectified");
          img.src = "/calibration/rectified.jpg?t=" + Date.now(); img.hidden = false;
        } else {
          out.textContent = "saved " + body.line + " in " + body.folder;
          const img = document.getElementById("capture-preview");
          img.src = "/captures/last.jpg?t=" + Date.now(); img.hidden = false;
        }
      } catch (error) {
        out.className = "action-result refused"; out.textContent = "failed: " + error;
      } finally {
        button.disabled = false;
      }
    });
  });
})();
