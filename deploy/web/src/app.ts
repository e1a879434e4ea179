// The page (filled in by the web runtime).
export {};
