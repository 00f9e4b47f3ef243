import { defineConfig } from "vitest/config";

// Built into backend/web (telerobot.server's package data: the wheel ships it), which
// the server serves at "/". During development
// `npx vite` proxies the API and the WebSocket to a running `telerobot serve`.
export default defineConfig({
  build: {
    outDir: "../backend/web",
    emptyOutDir: true,
    sourcemap: true,
    chunkSizeWarningLimit: 1200,
    // Three pages: the operator's, the camera calibration and the recordings' review.
    rollupOptions: { input: { main: "index.html", calibration: "calibration.html", review: "review.html" } },
  },
  server: {
    proxy: {
      "/api": "http://127.0.0.1:8000",
      "/ws": { target: "ws://127.0.0.1:8000", ws: true },
    },
  },
  test: { environment: "node" },
});
