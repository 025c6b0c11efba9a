// Starts the page (main.js); if that fails, says why in one line on the stage: three.js missing
// (the setup script installs it) or the error itself.

import("./main.js").catch(async (e) => {
  let text = `the viewer page failed to start: ${e && e.message ? e.message : e}`;
  try {
    const r = await fetch("three/build/three.module.js", { method: "HEAD" });
    if (r.status === 404) text = "three.js is not installed: run scripts/setup.sh (it runs npm ci), then restart the graph";
  } catch { /* the server is gone: the generic line stays */ }
  const box = document.getElementById("fatal");
  box.textContent = text;
  box.hidden = false;
  window.mocapgraphFatal = text;
});
