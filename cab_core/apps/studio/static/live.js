// cab-studio: a running attempt's page fetches itself again whenever its records change
// (data-rendered: the stamp of the records the page was rendered from).
"use strict";
(function () {
  const me = document.currentScript, url = me.dataset.stamp;
  let last = me.dataset.rendered;
  async function tick() {
    const r = await fetch(url); if (!r.ok) return true;
    const s = await r.json();
    if (s.stamp !== last) {
      const page = await (await fetch(location.href)).text();
      const doc = new DOMParser().parseFromString(page, "text/html");
      const next = doc.querySelector("script[data-rendered]");
      const y = window.scrollY;
      document.body.replaceWith(doc.body);  // its scripts do not run again: this loop goes on
      window.scrollTo(0, y);
      last = next ? next.dataset.rendered : s.stamp;
      return next !== null;  // a finished page has no stamp: nothing more to follow
    }
    return true;
  }
  function loop() { tick().then(go => { if (go) setTimeout(loop, 2000); }).catch(() => setTimeout(loop, 2000)); }
  setTimeout(loop, 2000);
})();
