// The sign-in page: a JSON request (never a form POST, which the console refuses), then the console.
"use strict";

const msg = document.getElementById("signin-message");
if (new URLSearchParams(location.search).get("failed")) {
  msg.textContent = "That sign-in link is wrong or was used already: the console prints a new one each time.";
  msg.className = "error";
}
document.getElementById("signin-form").onsubmit = async (ev) => {
  ev.preventDefault();
  const r = await fetch("/api/signin", {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({
      name: document.getElementById("signin-name").value,
      password: document.getElementById("signin-password").value,
    }),
  });
  if (r.ok) {
    location.href = "/";
    return;
  }
  const data = await r.json().catch(() => ({ error: `HTTP ${r.status}` }));
  msg.textContent = data.error || `HTTP ${r.status}`;
  msg.className = "error";
};
