// The console's link indicator, in a worker of its own: it pings the server once a second on a connection of its own
// (`/ws?role=link`: pongs only) and judges the link from the pongs, on a thread that drawing the 3D view or decoding
// a map never blocks (on a loaded two-core machine the page's main thread stalled for seconds, and a link judged
// there read "lost" while every message was arriving). It reports "ok" while pongs come back within 3 s, "connecting"
// until the first pong of a connection, "lost" otherwise, at once when the connection closes.
let socket = null, rtt = null, lastPong = 0, url = null;
function report() {
  const open = socket !== null && socket.readyState === 1;
  const fresh = open && rtt !== null && performance.now() - lastPong < 3000;
  postMessage({ state: fresh ? "ok" : open && rtt === null ? "connecting" : "lost", rtt });
}
function connect() {
  socket = new WebSocket(url);
  socket.onmessage = (event) => {
    const msg = JSON.parse(event.data);
    if (msg.type !== "pong") return;
    rtt = performance.now() - msg.t; lastPong = performance.now();
    report();
  };
  socket.onopen = ping;
  socket.onclose = () => { rtt = null; report(); setTimeout(connect, 1000); };
}
function ping() {
  if (socket && socket.readyState === 1) socket.send(JSON.stringify({ type: "ping", t: performance.now() }));
  report();
}
onmessage = (event) => { if (url === null) { url = event.data.url; connect(); setInterval(ping, 1000); } };
