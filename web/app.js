// The stagehand dashboard.
